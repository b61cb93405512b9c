"""The static-TF exports: one node publishing every unit's static transform, for ROS 2 (with a launch
file) or ROS 1; user data appear in it only as checked Python literals."""

from __future__ import annotations

from skincal.data.export.escape import plain_float, py_literal
from skincal.data.export.frames import UnitFrame, check_names
from skincal.data.result import CalibrationResult

# ---------------------------------------------------------------------- TF nodes
_TRANSFORMS_FN = '''

def transforms(stamp, message_type):
    """TRANSFORMS as messages of message_type (geometry_msgs TransformStamped) stamped stamp."""
    messages = []
    for parent, child, xyz, quaternion in TRANSFORMS:
        message = message_type()
        message.header.stamp = stamp
        message.header.frame_id = parent
        message.child_frame_id = child
        translation, rotation = message.transform.translation, message.transform.rotation
        translation.x, translation.y, translation.z = xyz
        rotation.x, rotation.y, rotation.z, rotation.w = quaternion
        messages.append(message)
    return messages
'''
"""The message builder both TF nodes share (ROS 1 and ROS 2 messages have the same fields)."""
_ROS2_HEAD = '''"""Static transforms of skin units calibrated by skincal, all sent at once by one ROS 2 node
(tf2_ros StaticTransformBroadcaster, latched). Run it as a launch file (ros2 launch <this file>) or
as a node (python3 <this file>). TRANSFORMS: (parent frame, child frame, (x, y, z) in m, quaternion
(x, y, z, w) in ROS order). CALIBRATION names the robot, the calibration method and the frames.
"""

import sys

'''
_ROS2_BODY = _TRANSFORMS_FN + '''

def main(args=None):
    import rclpy
    from geometry_msgs.msg import TransformStamped
    from tf2_ros.static_transform_broadcaster import StaticTransformBroadcaster

    rclpy.init(args=args)
    node = rclpy.create_node(NODE_NAME)
    broadcaster = StaticTransformBroadcaster(node)
    broadcaster.sendTransform(transforms(node.get_clock().now().to_msg(), TransformStamped))
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


def generate_launch_description():
    from launch import LaunchDescription
    from launch.actions import ExecuteProcess

    return LaunchDescription([ExecuteProcess(cmd=[sys.executable, __file__], name=NODE_NAME, output="screen")])


if __name__ == "__main__":
    main()
'''
_ROS1_HEAD = '''#!/usr/bin/env python3
"""Static transforms of skin units calibrated by skincal, all sent at once by one ROS 1 node
(tf2_ros StaticTransformBroadcaster, latched on /tf_static). Run it with python3 <this file>, or
make it executable in a package's scripts folder and start it from a launch file:
<node pkg="your_package" type="<this file>" name="skincal_skin_tf"/>. TRANSFORMS: (parent frame,
child frame, (x, y, z) in m, quaternion (x, y, z, w) in ROS order). CALIBRATION names the robot,
the calibration method and the frames.
"""

'''
_ROS1_BODY = _TRANSFORMS_FN + '''

def main():
    import rospy
    import tf2_ros
    from geometry_msgs.msg import TransformStamped

    rospy.init_node(NODE_NAME)
    broadcaster = tf2_ros.StaticTransformBroadcaster()
    broadcaster.sendTransform(transforms(rospy.Time.now(), TransformStamped))
    rospy.spin()


if __name__ == "__main__":
    main()
'''


def tf_transforms(frames: list[UnitFrame]) -> list[tuple]:
    """``(parent, child, (x, y, z), (qx, qy, qz, qw))`` per frame, ROS quaternion order."""
    out = []
    for f in frames:
        w, x, y, z = (plain_float(v) for v in f.quaternion_wxyz)
        out.append((str(f.parent), str(f.child), tuple(plain_float(v) for v in f.p_parent_child), (x, y, z, w)))
    return out


def _tf_node(result: CalibrationResult, frames: list[UnitFrame], frame: str, head: str, body: str) -> str:
    check_names(result, frames)
    rows = "".join(f"    {py_literal(t)},\n" for t in tf_transforms(frames))
    calibration = py_literal({"robot": str(result.robot), "method": str(result.method), "frame": frame})
    node = "skincal_skin_range_tf" if frame == "range" else "skincal_skin_tf"
    return head + f"CALIBRATION = {calibration}\nNODE_NAME = {py_literal(node)}\nTRANSFORMS = [\n{rows}]\n" + body


def to_tf_ros2(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> str:
    """One Python file that is a ROS 2 node (``rclpy``, one ``StaticTransformBroadcaster`` sending
    every unit's transform at once) and a launch file starting it; a fixed skeleton with user data
    only as literals (:func:`py_literal`)."""
    return _tf_node(result, frames, frame, _ROS2_HEAD, _ROS2_BODY)


def to_tf_ros1(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> str:
    """One ROS 1 node script (``rospy``, one ``tf2_ros.StaticTransformBroadcaster`` sending every
    unit's transform at once); a fixed skeleton with user data only as literals."""
    return _tf_node(result, frames, frame, _ROS1_HEAD, _ROS1_BODY)
