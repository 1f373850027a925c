"""Batched forward kinematics of a chain of 1-DOF revolute and prismatic joints: numba kernel and numpy reference.

Both multiply the model's own joint placements (read from Pinocchio by ArmKinematics)::

    T_joint[j] = T_joint[parent[j]] @ placement[j] @ M_j(q[idx[j]]),   T_joint[0] = T_root_to_world
    M_j(q) = Rot(axis[j], q) (kind 0, revolute) or Trans(axis[j] * q) (kind 1, prismatic)
    T_frame[f] = T_joint[frame_joint[f]] @ frame_placement[f]

The numpy twin is vectorised over configurations (one (N, 4, 4) product per joint); the numba kernel
loops over configurations without temporaries. Tests check both against Pinocchio.
"""

from __future__ import annotations

import numba
import numpy as np
from checks.numba_cache import key_cache_on_callees

__all__ = ["fk_frames_numba", "fk_frames_numpy"]


def _rodrigues_batch(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(N, 4, 4) rotations by ``angle`` (N,) rad about unit ``axis`` (3,)."""
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    out = np.zeros((angle.shape[0], 4, 4))
    out[:, :3, :3] = np.eye(3) + s * K + (1 - c) * (K @ K)
    out[:, 3, 3] = 1.0
    return out


def _translation_batch(axis: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """(N, 4, 4) translations by ``dist`` (N,) m along unit ``axis`` (3,)."""
    out = np.broadcast_to(np.eye(4), (dist.shape[0], 4, 4)).copy()
    out[:, :3, 3] = dist[:, None] * axis
    return out


def fk_frames_numpy(Q, T_root, placements, axes, kinds, parents, idx_q, frame_placements, frame_joints):
    """(N, n_frames, 4, 4) frame poses for Q (N, nq). placements (nj, 4, 4), axes (nj, 3) and kinds (nj,) int
    (0 revolute, 1 prismatic) index joints 1..nj-1 (row 0 is the root and unused); parents, idx_q (nj,) int;
    frame_placements (nf, 4, 4); frame_joints (nf,) int."""
    n = Q.shape[0]
    joints = [np.broadcast_to(T_root, (n, 4, 4))]
    for j in range(1, placements.shape[0]):
        move = _translation_batch if kinds[j] == 1 else _rodrigues_batch
        joints.append(joints[parents[j]] @ placements[j] @ move(axes[j], Q[:, idx_q[j]]))
    out = np.empty((n, frame_joints.shape[0], 4, 4))
    for k in range(frame_joints.shape[0]):
        out[:, k] = joints[frame_joints[k]] @ frame_placements[k]
    return out


@numba.njit(cache=True)
def _mul(A, B, out):
    for i in range(4):
        for j in range(4):
            acc = 0.0
            for k in range(4):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc


@numba.njit(cache=True)
def fk_frames_numba(Q, T_root, placements, axes, kinds, parents, idx_q, frame_placements, frame_joints):
    """Compiled twin of :func:`fk_frames_numpy` (same arguments, same result)."""
    n = Q.shape[0]
    nj = placements.shape[0]
    nf = frame_joints.shape[0]
    out = np.empty((n, nf, 4, 4))
    joints = np.empty((nj, 4, 4))
    local = np.empty((4, 4))
    rot = np.zeros((4, 4))
    rot[3, 3] = 1.0
    slide = np.zeros((4, 4))
    slide[3, 3] = 1.0
    for i in range(n):
        joints[0] = T_root
        for j in range(1, nj):
            x, y, z = axes[j, 0], axes[j, 1], axes[j, 2]
            if kinds[j] == 1:  # prismatic: a translation along the axis
                d = Q[i, idx_q[j]]
                for r in range(3):
                    for k in range(3):
                        slide[r, k] = 1.0 if r == k else 0.0
                slide[0, 3] = d * x
                slide[1, 3] = d * y
                slide[2, 3] = d * z
                _mul(placements[j], slide, local)
                _mul(joints[parents[j]], local, joints[j])
                continue
            c = np.cos(Q[i, idx_q[j]])
            s = np.sin(Q[i, idx_q[j]])
            t = 1.0 - c
            rot[0, 0] = c + t * x * x
            rot[0, 1] = t * x * y - s * z
            rot[0, 2] = t * x * z + s * y
            rot[1, 0] = t * x * y + s * z
            rot[1, 1] = c + t * y * y
            rot[1, 2] = t * y * z - s * x
            rot[2, 0] = t * x * z - s * y
            rot[2, 1] = t * y * z + s * x
            rot[2, 2] = c + t * z * z
            _mul(placements[j], rot, local)
            _mul(joints[parents[j]], local, joints[j])
        for k in range(nf):
            _mul(joints[frame_joints[k]], frame_placements[k], out[i, k])
    return out


key_cache_on_callees(globals())  # an edit of a helper it compiles in (another file too) recompiles a kernel
