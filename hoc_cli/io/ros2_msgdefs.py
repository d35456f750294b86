"""ROS 2 message definitions and QoS profiles as rosbag2 stores them in MCAP, for the MCAP writers
(``hoc_cli.io.mcap``, ``hoc_cli.io.mcap_markers``).

Message definitions: the type's own fields, then each dependency after a line of 80 '=' and a
"MSG: pkg/Type" line; the fields are those of ROS 2 Humble, which Iron and Jazzy keep unchanged for
every type here (``tests/test_ros2_humble.py`` checks them field by field against rosbags' Humble
and Jazzy type stores). Constants are left out (they are not serialised).

QoS: :func:`offered_qos_profiles` is the channel metadata value ``offered_qos_profiles`` in the
format rosbag2 Humble writes (a YAML list of profiles with the rmw enums as integers). rosbag2 Jazzy
and later detect that format from the integer ``history`` and read it as well; Humble cannot read
the string enums that Jazzy writes, so integers are the form both read.
"""
from __future__ import annotations

_SEP = "=" * 80 + "\n"


def _msg(name: str, fields: str) -> str:
    return _SEP + f"MSG: {name}\n" + fields


_TIME = _msg("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n")
_DURATION = _msg("builtin_interfaces/Duration", "int32 sec\nuint32 nanosec\n")
_HEADER = _msg("std_msgs/Header", "builtin_interfaces/Time stamp\nstring frame_id\n") + _TIME
_VECTOR3 = _msg("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n")
_POINT = _msg("geometry_msgs/Point", "float64 x\nfloat64 y\nfloat64 z\n")
_QUATERNION = _msg("geometry_msgs/Quaternion", "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n")
_POSE = _msg("geometry_msgs/Pose", "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n")
_COLOR = _msg("std_msgs/ColorRGBA", "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n")

#: visualization_msgs/Marker fields (Humble and later: texture_*, uv_coordinates and mesh_file included)
_MARKER_FIELDS = (
    "std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\ngeometry_msgs/Pose pose\n"
    "geometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\nbuiltin_interfaces/Duration lifetime\n"
    "bool frame_locked\ngeometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\n"
    "string texture_resource\nsensor_msgs/CompressedImage texture\n"
    "visualization_msgs/UVCoordinate[] uv_coordinates\nstring text\nstring mesh_resource\n"
    "visualization_msgs/MeshFile mesh_file\nbool mesh_use_embedded_materials\n"
)
_MARKER_DEPS = (
    _HEADER + _POSE + _POINT + _QUATERNION + _VECTOR3 + _COLOR + _DURATION
    + _msg("sensor_msgs/CompressedImage", "std_msgs/Header header\nstring format\nuint8[] data\n")
    + _msg("visualization_msgs/UVCoordinate", "float32 u\nfloat32 v\n")
    + _msg("visualization_msgs/MeshFile", "string filename\nuint8[] data\n")
)

MSGDEFS: dict[str, str] = {
    "std_msgs/msg/String": "string data\n",
    "std_msgs/msg/Float64": "float64 data\n",
    "sensor_msgs/msg/JointState": (
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n" + _HEADER
    ),
    "trajectory_msgs/msg/JointTrajectory": (
        "std_msgs/Header header\nstring[] joint_names\ntrajectory_msgs/JointTrajectoryPoint[] points\n"
        + _HEADER
        + _msg("trajectory_msgs/JointTrajectoryPoint", "float64[] positions\nfloat64[] velocities\n"
               "float64[] accelerations\nfloat64[] effort\nbuiltin_interfaces/Duration time_from_start\n")
        + _DURATION
    ),
    "tf2_msgs/msg/TFMessage": (
        "geometry_msgs/TransformStamped[] transforms\n"
        + _msg("geometry_msgs/TransformStamped", "std_msgs/Header header\nstring child_frame_id\n"
               "geometry_msgs/Transform transform\n")
        + _HEADER
        + _msg("geometry_msgs/Transform", "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n")
        + _VECTOR3 + _QUATERNION
    ),
    "visualization_msgs/msg/Marker": _MARKER_FIELDS + _MARKER_DEPS,
    "visualization_msgs/msg/MarkerArray": (
        "visualization_msgs/Marker[] markers\n" + _msg("visualization_msgs/Marker", _MARKER_FIELDS) + _MARKER_DEPS
    ),
}

# rmw enum values (rmw/types.h), as rosbag2 Humble serialises them
HISTORY_KEEP_LAST = 1
RELIABILITY_RELIABLE = 1
DURABILITY_TRANSIENT_LOCAL, DURABILITY_VOLATILE = 1, 2
LIVELINESS_AUTOMATIC = 1


def offered_qos_profiles(*, latched: bool) -> str:
    """The ``offered_qos_profiles`` channel metadata of one publisher: reliable, keep-last, and
    transient-local with depth 1 when ``latched`` (what ``/robot_description`` and ``/tf_static``
    publishers offer, so a late subscriber still gets the message), else volatile with depth 10.
    Deadline, lifespan and liveliness lease are 0 s, 0 ns: "unspecified", the RMW default (infinite).
    """
    zero = "\n    sec: 0\n    nsec: 0"
    return (f"- history: {HISTORY_KEEP_LAST}\n  depth: {1 if latched else 10}\n  reliability: {RELIABILITY_RELIABLE}\n"
            f"  durability: {DURABILITY_TRANSIENT_LOCAL if latched else DURABILITY_VOLATILE}\n"
            f"  deadline:{zero}\n  lifespan:{zero}\n  liveliness: {LIVELINESS_AUTOMATIC}\n"
            f"  liveliness_lease_duration:{zero}\n  avoid_ros_namespace_conventions: false")
