"""Robot models: URDF loading (:mod:`.urdf`) into a frozen array tree (:mod:`.tree`)."""
from .tree import RobotModel
from .urdf import load_robot, urdf_joint_table, urdf_link_table

__all__ = ["RobotModel", "load_robot", "urdf_joint_table", "urdf_link_table"]
