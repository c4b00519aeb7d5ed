"""Central finite differences shared by the derivative tests."""

import numpy as np


def central_fd(f, q, h):
    """Central differences of f: (n, 6) -> array, w.r.t. every entry of q; shape f.shape + (n, 6)."""
    f0 = np.asarray(f(q))
    out = np.zeros(f0.shape + q.shape)
    for k in range(q.shape[0]):
        for j in range(q.shape[1]):
            qp, qm = q.copy(), q.copy()
            qp[k, j] += h
            qm[k, j] -= h
            out[..., k, j] = (np.asarray(f(qp)) - np.asarray(f(qm))) / (2 * h)
    return out
