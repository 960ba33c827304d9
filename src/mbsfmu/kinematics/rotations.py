"""Rotation matrices, the cross-product matrix and unit quaternions (scalar first)."""

import math

import numpy as np


def skew(a):
    """ã: the matrix with ã·b = a × b."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def cross(a, b):
    """a × b for 3-vectors (cheaper than np.cross for single vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def axis_angle(axis, angle):
    """Rodrigues: rotation by `angle` about the unit vector `axis`."""
    x, y, z = axis
    c, s = math.cos(angle), math.sin(angle)
    C = 1.0 - c
    return np.array([[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
                     [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
                     [z * x * C - y * s, z * y * C + x * s, c + z * z * C]])


def quat_to_matrix(p):
    """S(p) for a unit quaternion p = (p0, p1, p2, p3), scalar first."""
    p0, p1, p2, p3 = p
    return np.array([[1 - 2 * (p2 * p2 + p3 * p3), 2 * (p1 * p2 - p0 * p3), 2 * (p1 * p3 + p0 * p2)],
                     [2 * (p1 * p2 + p0 * p3), 1 - 2 * (p1 * p1 + p3 * p3), 2 * (p2 * p3 - p0 * p1)],
                     [2 * (p1 * p3 - p0 * p2), 2 * (p2 * p3 + p0 * p1), 1 - 2 * (p1 * p1 + p2 * p2)]])


def matrix_to_quat(S):
    """Unit quaternion (scalar first, p0 >= 0) of a rotation matrix (Shepperd's method)."""
    t = np.trace(S)
    cands = [t, S[0, 0], S[1, 1], S[2, 2]]
    i = int(np.argmax(cands))
    if i == 0:
        r = math.sqrt(1 + t) * 2
        p = [0.25 * r, (S[2, 1] - S[1, 2]) / r, (S[0, 2] - S[2, 0]) / r, (S[1, 0] - S[0, 1]) / r]
    elif i == 1:
        r = math.sqrt(1 + 2 * S[0, 0] - t) * 2
        p = [(S[2, 1] - S[1, 2]) / r, 0.25 * r, (S[0, 1] + S[1, 0]) / r, (S[0, 2] + S[2, 0]) / r]
    elif i == 2:
        r = math.sqrt(1 + 2 * S[1, 1] - t) * 2
        p = [(S[0, 2] - S[2, 0]) / r, (S[0, 1] + S[1, 0]) / r, 0.25 * r, (S[1, 2] + S[2, 1]) / r]
    else:
        r = math.sqrt(1 + 2 * S[2, 2] - t) * 2
        p = [(S[1, 0] - S[0, 1]) / r, (S[0, 2] + S[2, 0]) / r, (S[1, 2] + S[2, 1]) / r, 0.25 * r]
    p = np.array(p)
    return p if p[0] >= 0 else -p


def quat_rate_matrix(p):
    """G(p) with ṗ = G(p)·ω for body-frame angular velocity ω (ṗ = ½ p ⊗ (0, ω))."""
    p0, p1, p2, p3 = p
    return 0.5 * np.array([[-p1, -p2, -p3], [p0, -p3, p2], [p3, p0, -p1], [-p2, p1, p0]])


def quat_exp_step(p, dphi):
    """p ⊗ exp(dphi/2): rotate p by the body-frame rotation vector dphi (keeps unit length)."""
    a = math.sqrt(dphi[0] ** 2 + dphi[1] ** 2 + dphi[2] ** 2)
    if a < 1e-12:
        d = np.array([1.0, 0.5 * dphi[0], 0.5 * dphi[1], 0.5 * dphi[2]])
    else:
        s = math.sin(0.5 * a) / a
        d = np.array([math.cos(0.5 * a), s * dphi[0], s * dphi[1], s * dphi[2]])
    p0, p1, p2, p3 = p
    q0, q1, q2, q3 = d
    out = np.array([p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3, p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
                    p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1, p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0])
    return out / math.sqrt(out @ out)


def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
