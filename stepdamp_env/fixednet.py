"""The learned policies' networks in fixed-order arithmetic (:mod:`.fixedmath`):
a feed-forward network and an LSTM step whose every sum runs in input order in
float64, so a policy's action has the same bits on every x86-64 CPU and batch
size (``tests/test_fixedmath.py``, ``tests/test_cpu_determinism.py``)."""

from __future__ import annotations

import numpy as np
from numba import njit

from .fields import layout
from .fixedmath import exp, tanh

__all__ = ["ACTIVATION", "mlp_forward", "lstm_step"]

# numba without fastmath: no reassociation, no contraction into FMA.
_jit = njit(cache=True, error_model="numpy")

# Activations of mlp_forward's layers.
ACTIVATION = layout("Activation", """
    IDENTITY  no activation
    RELU      max(x, 0)
    TANH      tanh(x)
""")


@_jit
def mlp_forward(x, weights, biases, sizes, activations):
    """A feed-forward network on each row of ``x`` (float32 or float64, n x d):
    layer l maps sizes[l] inputs to sizes[l+1] outputs, ``weights`` holds every
    layer's (out, in) matrix row by row and ``biases`` their biases, one after
    the other, ``activations[l]`` is an ``ACTIVATION`` code. Every sum runs in
    input order in float64, whatever the batch size; returns float64 (n x out).

    32 rows at a time, the loop over them innermost: SIMD across rows (no
    reassociation within a row's sum, so the same bits as one row alone)."""
    n = x.shape[0]
    rows = 32
    layers = activations.size
    width = 0
    for s in sizes:
        width = max(width, s)
    out = np.empty((n, sizes[layers]))
    a = np.zeros((width, rows))
    z = np.zeros((width, rows))
    for first in range(0, n, rows):
        m = min(rows, n - first)
        for i in range(sizes[0]):
            for r in range(m):
                a[i, r] = float(x[first + r, i])
        w_at = 0
        b_at = 0
        for layer in range(layers):
            n_in, n_out = sizes[layer], sizes[layer + 1]
            act = activations[layer]
            for o in range(n_out):
                zo = z[o]
                b = biases[b_at + o]
                for r in range(rows):
                    zo[r] = b
                base = w_at + o * n_in
                # Four inputs per pass over the rows, added in input order.
                i = 0
                while i + 4 <= n_in:
                    w0, w1 = weights[base + i], weights[base + i + 1]
                    w2, w3 = weights[base + i + 2], weights[base + i + 3]
                    a0, a1, a2, a3 = a[i], a[i + 1], a[i + 2], a[i + 3]
                    for r in range(rows):
                        zo[r] = (((zo[r] + w0 * a0[r]) + w1 * a1[r]) + w2 * a2[r]) + w3 * a3[r]
                    i += 4
                while i < n_in:
                    w = weights[base + i]
                    ai = a[i]
                    for r in range(rows):
                        zo[r] += w * ai[r]
                    i += 1
                if act == ACTIVATION.RELU:
                    for r in range(rows):
                        zo[r] = zo[r] if zo[r] > 0.0 else 0.0
                elif act == ACTIVATION.TANH:
                    for r in range(m):
                        zo[r] = tanh(zo[r])
            for o in range(n_out):
                for r in range(rows):
                    a[o, r] = z[o, r]
            w_at += n_in * n_out
            b_at += n_out
        for r in range(m):
            for o in range(sizes[layers]):
                out[first + r, o] = a[o, r]
    return out


@_jit
def lstm_step(x, rows, h, c, w_ih, w_hh, bias):
    """One step of a one-layer LSTM (torch's gate order i, f, g, o) for each row
    ``r = rows[k]`` of the state: ``x[k]`` (n x d, float32 or float64) the input,
    ``h[r]`` and ``c[r]`` (float64, H wide) the hidden and cell state, updated in
    place. ``w_ih`` (4H x d) and ``w_hh`` (4H x H) row by row, ``bias`` (4H) the
    sum of torch's two biases. Every sum in input order in float64."""
    hidden = h.shape[1]
    d = x.shape[1]
    gates = np.empty(4 * hidden)
    for k in range(rows.size):
        r = rows[k]
        for g in range(4 * hidden):
            s = bias[g]
            for i in range(d):
                s += w_ih[g * d + i] * float(x[k, i])
            for j in range(hidden):
                s += w_hh[g * hidden + j] * h[r, j]
            gates[g] = s
        for j in range(hidden):
            gi = 1.0 / (1.0 + exp(-gates[j]))
            gf = 1.0 / (1.0 + exp(-gates[hidden + j]))
            gg = tanh(gates[2 * hidden + j])
            go = 1.0 / (1.0 + exp(-gates[3 * hidden + j]))
            c[r, j] = gf * c[r, j] + gi * gg
            h[r, j] = go * tanh(c[r, j])
