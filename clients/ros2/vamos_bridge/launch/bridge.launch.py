"""One robot's bridge: ``ros2 launch vamos_bridge bridge.launch.py namespace:=robot1
profile:=my-profile``.

The node runs in ``namespace``, so its relative topics (camera/image_raw, joint_states,
vamos/frame_score...) resolve under it and several robots share one graph. Parameters
come from ``params_file`` (default: the package's config/vamos_bridge.yaml); ``profile``,
``server`` and ``depth_topic``, when given, override the file's (``depth_topic:=
camera/aligned_depth_to_color/image_raw`` sends each image with its depth image).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

OVERRIDES = ("profile", "server", "depth_topic")


def _bridge(context, *args, **kwargs):
    given = {name: LaunchConfiguration(name).perform(context) for name in OVERRIDES}
    overrides = {name: value for name, value in given.items() if value}
    return [Node(
        package="vamos_bridge",
        executable="bridge",
        name="vamos_bridge",
        namespace=LaunchConfiguration("namespace"),
        parameters=[LaunchConfiguration("params_file"), *([overrides] if overrides else [])],
        output="screen",
    )]


def generate_launch_description():
    default_params = PathJoinSubstitution([FindPackageShare("vamos_bridge"), "config", "vamos_bridge.yaml"])
    return LaunchDescription([
        DeclareLaunchArgument("namespace", default_value="",
                              description="the robot's namespace; the bridge's topics resolve under it"),
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="parameters YAML (see config/vamos_bridge.yaml)"),
        DeclareLaunchArgument("profile", default_value="",
                              description="the vamos profile to score with (default: the file's)"),
        DeclareLaunchArgument("server", default_value="",
                              description="vamos serve's gRPC address (default: the file's)"),
        DeclareLaunchArgument("depth_topic", default_value="",
                              description="depth images registered to the camera's (default: the file's, none)"),
        OpaqueFunction(function=_bridge),
    ])
