"""msgs_py: conversions between climb_msgs / geometry_msgs messages and the library's types.

Nothing here calls rclpy.init() or imports rclpy (only the env_probe node does). Naming:
``<thing>_to_msg`` / ``<thing>_from_msg``; every ``_from_msg`` validates its input and raises
climb_core.errors.SpecError naming the offending field.
"""
from .commands import (CLIMB_PHASES, CONTROLLER_MODES, GRIPPER_COMMANDS, JOINT_MODES, QP_STATUS,
                       ClimbStatusData, ControllerStateData, GripperCommandData, JointCommandData,
                       climb_status_from_msg, climb_status_to_msg, controller_state_from_msg,
                       controller_state_to_msg, gripper_command_from_msg, gripper_command_to_msg,
                       joint_command_from_msg, joint_command_to_msg, validate_joint_command)
from .contact import (FREE_FLYER_NQ, configuration_from_msg, configuration_to_msg, contact_plan_from_msg,
                      contact_plan_to_msg, contact_point_from_msg, contact_point_to_msg, guide_path_from_msg,
                      guide_path_to_msg, hold_from_msg, hold_to_msg, stance_from_msg, stance_to_msg,
                      transition_from_msg, transition_to_msg, whole_body_plan_from_msg, whole_body_plan_to_msg)
from .geometry import (point_from_msg, point_to_msg, pose_from_msg, pose_to_msg, quaternion_from_msg,
                       quaternion_to_msg, quaternion_to_rotation, rotation_to_quaternion, vector3_from_msg,
                       vector3_to_msg, wrench_from_msg, wrench_to_msg)
from .stamps import (WORLD_FRAME, duration_to_seconds, header_stamp, make_header, quantize_seconds,
                     seconds_to_duration, seconds_to_time, time_to_seconds)

__all__ = [name for name in dir() if not name.startswith("_")]
