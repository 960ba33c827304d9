"""Rotations and joint motion (joint-frame kinematics)."""
