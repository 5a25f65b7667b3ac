"""Launch one robot's camera node in its namespace: ros2 launch swarm_phd_camera camera.launch.py
robot:=ugv_3 front_calibration:=/path/front.yaml back_calibration:=/path/back.yaml"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    robot = LaunchConfiguration("robot")
    return LaunchDescription(
        [
            DeclareLaunchArgument("robot", description="the robot's id, e.g. ugv_3"),
            DeclareLaunchArgument("front_calibration"),
            DeclareLaunchArgument("back_calibration"),
            Node(
                package="swarm_phd_camera",
                executable="camera_node",
                namespace=robot,
                parameters=[
                    {
                        "front_calibration": LaunchConfiguration("front_calibration"),
                        "back_calibration": LaunchConfiguration("back_calibration"),
                        "frame_id": [robot, "/base_link"],
                    }
                ],
            ),
        ]
    )
