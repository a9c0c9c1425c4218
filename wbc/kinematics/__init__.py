"""Tool-point kinematics and inverse kinematics."""

from wbc.kinematics.tcp_ik import IKResult, solve_tcp_ik
from wbc.kinematics.tcp_kinematics import TcpKinematics

__all__ = ["IKResult", "TcpKinematics", "solve_tcp_ik"]
