"""Write a bag of BallDetection messages with mcap-ros2-support (not ttball), for ttball to
replay: a ball flying toward the robot at 150 fps (gravity and drag), in the table frame.

Usage: write_bag.py OUT.mcap MSG_DIR
MSG_DIR is ttball's msgs/msg, whose BallDetection.msg is the schema's first part.
"""

import math
import sys

from mcap_ros2.writer import Writer

SEPARATOR = "=" * 80
DEPENDENCIES = {
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
}


def main():
    out, msg_dir = sys.argv[1], sys.argv[2]
    with open(f"{msg_dir}/BallDetection.msg") as f:
        text = f.read()
    for name, body in DEPENDENCIES.items():
        text += f"\n{SEPARATOR}\nMSG: {name}\n{body}"
    with open(out, "wb") as f:
        writer = Writer(f)
        schema = writer.register_msgdef("ttball_msgs/msg/BallDetection", text)
        start = 1_700_000_000_000_000_000
        g = 9.80665
        k_drag = 0.27925 * 0.3682  # rho S_b / m * C_D(0): ttball's default ball without spin
        p, v = [1.2, 0.0, 0.30], [-4.0, 0.05, 1.0]
        for k in range(45):  # 0.3 s at 150 fps, still above the table
            t = k / 150.0
            x, y, z = p
            stamp = start + round(t * 1e9)
            message = {
                "header": {"stamp": {"sec": stamp // 10**9, "nanosec": stamp % 10**9}, "frame_id": "table"},
                "position": {"x": x, "y": y, "z": z},
                "position_covariance": [0.0] * 9,
                "has_spin": False,
                "spin": {"x": 0.0, "y": 0.0, "z": 0.0},
                "spin_covariance": [0.0] * 9,
                "source": 1,
                "confidence": 0.9,
            }
            writer.write_message("/ball/detections", schema, message, log_time=stamp + 8_000_000, publish_time=stamp + 8_000_000)
            for _ in range(200):  # to the next frame: gravity and drag, small Euler steps
                h = 1.0 / 150.0 / 200
                speed = math.sqrt(sum(c * c for c in v))
                a = [-k_drag * speed * v[0], -k_drag * speed * v[1], -g - k_drag * speed * v[2]]
                p = [p[i] + h * v[i] for i in range(3)]
                v = [v[i] + h * a[i] for i in range(3)]
        writer.finish()


if __name__ == "__main__":
    main()
