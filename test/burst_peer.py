"""The two peers of ``test_dds_transport``'s burst test, each run as its own process.

``reader SIZE BURSTS``: subscribes (reliable, deep enough for every burst) to
``burst`` with whatever Fast DDS set-up its environment names, prints
``matched`` once it has matched the writer, and ``burst K <seconds>`` when the
K-th burst (data K * SIZE + i) has arrived whole, timed from its first message.

``writer SIZE BURSTS GO_FILE``: a package node's DDS set-up
(:func:`~hill_muscle_ros.dds_transport.use_udp_transport`, as ``run_node``
calls it). Once the reader is matched and ``GO_FILE`` exists, it publishes the
bursts one after the other, each once the last is acknowledged.
"""
import os
import sys
import time

from hill_muscle_ros.dds_transport import use_udp_transport

#: [s] how long the writer waits for a burst's acknowledgement
ACK_TIMEOUT_S = 30.0
#: [s] spin slice while waiting
SLICE_S = 0.05


def main() -> None:
    role, size, bursts = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    if role == 'writer':
        print(use_udp_transport(), flush=True)
    import rclpy   # after the transport is set, as run_node does
    from rclpy.duration import Duration
    from rclpy.qos import QoSProfile
    from std_msgs.msg import Float64

    rclpy.init()
    node = rclpy.create_node(f'burst_{role}')
    qos = QoSProfile(depth=size * bursts)
    if role == 'writer':
        go_file = sys.argv[4]
        pub = node.create_publisher(Float64, 'burst', qos)
        while pub.get_subscription_count() == 0 or not os.path.exists(go_file):
            rclpy.spin_once(node, timeout_sec=SLICE_S)
        for k in range(bursts):
            for i in range(size):
                pub.publish(Float64(data=float(k * size + i)))
            acked = pub.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
            print(f'burst {k} acknowledged: {acked}', flush=True)
    else:
        counts, first_s = [0] * bursts, [0.0] * bursts

        def on_message(msg) -> None:
            k = int(msg.data) // size
            if counts[k] == 0:
                first_s[k] = time.monotonic()
            counts[k] += 1
            if counts[k] == size:
                print(f'burst {k} {time.monotonic() - first_s[k]:.3f}', flush=True)

        sub = node.create_subscription(Float64, 'burst', on_message, qos)
        while sub.get_publisher_count() == 0:
            rclpy.spin_once(node, timeout_sec=SLICE_S)
        print('matched', flush=True)
        while sum(counts) < size * bursts:
            rclpy.spin_once(node, timeout_sec=SLICE_S)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == '__main__':
    main()
