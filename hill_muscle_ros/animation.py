"""A limb run as a stick figure, written as an animated GIF.

The proximal segment is fixed and drawn grey; the moving segment turns with
the joint angle theta (from hanging vertical, positive in extension). A knee
shows the thigh (horizontal, seated), the shank and the foot; an ankle
(``joint.name`` containing ``ankle``) shows the vertical shank and the foot.
Each muscle is a line from the fixed segment to the moving one, on the side it
pulls (extensors in front, flexors behind), coloured by its recruitment R
(activation) from grey (0) to red (1). The frames sample the simulation at a
fixed frame rate of simulated time and are written with matplotlib's
``PillowWriter``.

The segment lengths are for the picture only (a 1.75 m adult); the dynamics
use the plant file's inertia, mass and centre of mass.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.animation import PillowWriter
from matplotlib.colors import LinearSegmentedColormap
from matplotlib.figure import Figure

from .model.limb import LimbPlant, LimbResult

#: [inch] frame size and [dots per inch]: 400 x 400 pixels keeps a GIF of a few
#: seconds at 25 fps under about a megabyte.
FIGSIZE_IN = (4.0, 4.0)
DPI = 100
#: [m] drawn segment lengths of a 1.75 m adult (picture only).
THIGH_M = 0.43
SHANK_M = 0.43
FOOT_M = 0.22
#: [m] how far in front of / behind the bones a muscle line runs, and where on
#: the fixed segment (share of its length from the joint) it starts.
MUSCLE_OFFSET_M = 0.035
MUSCLE_ORIGIN_SHARE = 0.6
#: [m] insertion on the moving segment, from the joint along it.
KNEE_INSERTION_M = 0.08
ANKLE_INSERTION_M = 0.06
#: Muscle colours: grey when not recruited to red when fully recruited.
ACTIVATION_CMAP = LinearSegmentedColormap.from_list('activation', ['0.75', 'tab:red'])
BONE_COLOR, FIXED_COLOR = '0.15', '0.55'
#: [m] half-width of the drawing area around the joint.
VIEW_M = 0.55


def _unit(theta: float) -> tuple[np.ndarray, np.ndarray]:
    """The moving segment's direction d (hanging: straight down, turning forward
    as theta grows) and its front normal n."""
    d = np.array([math.sin(theta), -math.cos(theta)])
    n = np.array([math.cos(theta), math.sin(theta)])
    return d, n


@dataclass(frozen=True)
class Pose:
    """Points of one frame, joint at the origin [m].

    :param fixed: the fixed segment (two points)
    :param moving: the moving segment and, for a knee, the foot (polyline)
    :param muscles: per muscle, its line (polyline)
    """

    fixed: np.ndarray
    moving: np.ndarray
    muscles: list


def pose(plant: LimbPlant, theta: float) -> Pose:
    """The stick figure at joint angle ``theta`` [rad]."""
    d, n = _unit(theta)
    ankle = 'ankle' in plant.joint.name.lower()
    if ankle:
        along, front = np.array([0.0, 1.0]), np.array([1.0, 0.0])   # shank up, front +x
        fixed = np.array([[0.0, 0.0], along * SHANK_M])
        moving = np.array([[0.0, 0.0], d * FOOT_M])
        origin_len, insertion = SHANK_M, ANKLE_INSERTION_M
    else:
        along, front = np.array([-1.0, 0.0]), np.array([0.0, 1.0])  # thigh to the hip, top
        fixed = np.array([along * THIGH_M, [0.0, 0.0]])
        heel = d * SHANK_M
        moving = np.array([[0.0, 0.0], heel, heel + n * FOOT_M])
        origin_len, insertion = THIGH_M, KNEE_INSERTION_M
    lines = []
    for m in plant.muscles:
        side = 1.0 if m.action == 'extensor' else -1.0
        start = along * MUSCLE_ORIGIN_SHARE * origin_len + side * front * MUSCLE_OFFSET_M
        if side > 0.0:
            # An extensor wraps over the front of the joint (the patella at the knee).
            over = front * MUSCLE_OFFSET_M
            end = d * insertion + n * MUSCLE_OFFSET_M
            lines.append(np.array([start, over, end]))
        else:
            # A flexor runs straight behind: to the back of the shank, or the heel.
            end = -d * ANKLE_INSERTION_M if ankle else d * insertion - n * MUSCLE_OFFSET_M
            lines.append(np.array([start, end]))
    return Pose(fixed, moving, lines)


def frame_indices(t_s: np.ndarray, fps: float) -> np.ndarray:
    """Sample indices at every 1 / fps of simulated time, from 0 to the end."""
    n_frames = int(math.floor(float(t_s[-1]) * fps + 1e-9)) + 1
    wanted = np.arange(n_frames) / fps
    return np.clip(np.searchsorted(t_s, wanted - 1e-9), 0, len(t_s) - 1)


def write_gif(path: str | Path, plant: LimbPlant, result: LimbResult,
              fps: float = 25.0) -> int:
    """Write the run as an animated GIF.

    :param path: the GIF file (parent directories are created)
    :param plant: the plant that was simulated
    :param result: its run (:func:`~hill_muscle_ros.model.limb.simulate_limb`)
    :param fps: [frames/s] frames per second of simulated time
    :return: the number of frames written
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI)
    ax = fig.add_axes((0.02, 0.02, 0.96, 0.86))
    ax.set_xlim(-VIEW_M, VIEW_M)
    ax.set_ylim(-VIEW_M, VIEW_M)
    ax.set_aspect('equal')
    ax.axis('off')
    first = pose(plant, float(result['theta_rad'][0]))
    ax.plot(*first.fixed.T, color=FIXED_COLOR, linewidth=7, solid_capstyle='round')
    moving, = ax.plot(*first.moving.T, color=BONE_COLOR, linewidth=6,
                      solid_capstyle='round', solid_joinstyle='round')
    muscles = [ax.plot(*line.T, linewidth=4, solid_capstyle='round')[0]
               for line in first.muscles]
    ax.plot([0.0], [0.0], 'o', color='white', markeredgecolor=BONE_COLOR, markersize=9,
            zorder=5)
    title = fig.text(0.5, 0.95, '', ha='center', va='center', fontsize=10)
    legend = fig.text(0.5, 0.90, '', ha='center', va='center', fontsize=8)
    names = [m.name for m in plant.muscles]

    indices = frame_indices(result.t_s, fps)
    writer = PillowWriter(fps=fps)
    with writer.saving(fig, str(path), DPI):
        for k in indices:
            theta = float(result['theta_rad'][k])
            p = pose(plant, theta)
            moving.set_data(*p.moving.T)
            activations = [float(result[f'{n}_recruitment'][k]) for n in names]
            for line, points, a in zip(muscles, p.muscles, activations):
                line.set_data(*points.T)
                line.set_color(ACTIVATION_CMAP(a))
            title.set_text(f'{plant.joint.name}: t = {result.t_s[k]:5.2f} s, '
                           f'angle {math.degrees(theta):6.1f} deg')
            legend.set_text('   '.join(f'{n} R = {a:.2f}' for n, a in zip(names, activations)))
            writer.grab_frame()
    return len(indices)
