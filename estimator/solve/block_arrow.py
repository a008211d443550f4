"""Normal equations of a block-arrow least-squares problem, solved by the Schur complement.

The Jacobian J (rows, size) of the batch objective has global columns that any row may touch (the
state, and the self-calibration's nuisance parameters) and, per frame, a local block of columns
(that frame's flange pose error delta) that only the frame's own rows touch. Eliminating the local
blocks leaves the Schur complement over the global columns,

    S = A - sum_i B_i inv(D_i) B_i^T,   A = J_g^T J_g,  B_i = J_g,i^T J_l,i,  D_i = J_l,i^T J_l,i,

so the normal equations cost a few small products per frame instead of a dense (size, size) system.
Rows outside every local block (priors) touch global columns only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BlockLayout:
    """global_columns: (g,) the columns any row may touch, ascending. local: per frame, (its rows,
    its local columns); every other column of those rows is zero."""

    global_columns: np.ndarray
    local: list[tuple[slice, slice]]


@dataclass
class SchurSystem:
    """J^T J reduced to the global columns: S (g, g), and per local block K_i = inv(D_i) B_i^T
    (k, g) and inv(D_i) (k, k)."""

    layout: BlockLayout
    S: np.ndarray
    K: list[np.ndarray]
    D_inv: list[np.ndarray]


def schur_system(J: np.ndarray, layout: BlockLayout) -> SchurSystem:
    """The Schur complement of J^T J (J: (rows, size) with layout's structure)."""
    G = J[:, layout.global_columns]
    S = G.T @ G
    blocks = [J[rows, cols] for rows, cols in layout.local]
    D_inv = list(np.linalg.inv(np.array([L.T @ L for L in blocks]))) if blocks else []  # one call, all frames
    K = []
    for (rows, _), L, Di in zip(layout.local, blocks, D_inv, strict=True):
        Ki = Di @ (L.T @ G[rows])
        S -= (G[rows].T @ L) @ Ki
        K.append(Ki)
    return SchurSystem(layout, S, K, D_inv)


def normal_solve(J: np.ndarray, r: np.ndarray, layout: BlockLayout) -> np.ndarray:
    """(size,) x with J^T J x = J^T r, by the Schur complement over layout's local blocks."""
    system = schur_system(J, layout)
    g = layout.global_columns
    c = J[:, g].T @ r
    local_rhs = [J[rows, cols].T @ r[rows] for rows, cols in layout.local]
    for Ki, b in zip(system.K, local_rhs, strict=True):
        c -= Ki.T @ b
    x = np.zeros(J.shape[1])
    x[g] = np.linalg.solve(system.S, c)
    for (_, cols), Ki, Di, b in zip(layout.local, system.K, system.D_inv, local_rhs, strict=True):
        x[cols] = Di @ b - Ki @ x[g]
    return x


def global_inverse(J: np.ndarray, layout: BlockLayout) -> np.ndarray:
    """(g, g) the global columns' block of inv(J^T J): inv(S)."""
    return np.linalg.inv(schur_system(J, layout).S)


def hat_diagonal(J: np.ndarray, layout: BlockLayout) -> np.ndarray:
    """(rows,) the diagonal of J inv(J^T J) J^T. A frame row j = [a, l] (global, local parts) has
    (a - l K) inv(S) (a - l K)^T + l inv(D) l^T."""
    system = schur_system(J, layout)
    S_inv = np.linalg.inv(system.S)
    V = J[:, layout.global_columns]
    hat = np.zeros(len(J))
    for (rows, cols), Ki, Di in zip(layout.local, system.K, system.D_inv, strict=True):
        L = J[rows, cols]
        V[rows] = V[rows] - L @ Ki
        hat[rows] = np.einsum("ij,ij->i", L @ Di, L)
    return hat + np.einsum("ij,ij->i", V @ S_inv, V)
