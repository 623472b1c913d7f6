"""The user-facing tools: the ``hill-muscle`` command and what its subcommands run.

- :mod:`.cli`: the ``hill-muscle`` console script: parses the command line and
  dispatches to the subcommands (``simulate`` of one muscle is its own);
- :mod:`.limb_cli`: ``simulate --plant`` (a limb) and ``animate``;
- :mod:`.fit`: ``fit``, parameters from a recorded bag by least squares;
- :mod:`.sweep`: ``sweep``, one protocol over many parameter sets on Dask;
- :mod:`.figures`: ``figures``, the paper's figures and those of the extensions.

Nothing here is imported by the model, the nodes or the recording code: the
tools sit on top of them. This package imports none of its modules itself, so
that a command loads only what it needs.
"""
