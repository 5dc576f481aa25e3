"""The compiled relaxation loop of the snakes.

One Numba kernel runs a whole relaxation of a :class:`~trackers.snakes.ContourSystem`
(see the module docstring of :mod:`trackers.snakes`): force sampling from fields or
potentials, explicit tension, rest-length update, the banded solve with the factor
computed once and the cyclic correction of closed contours, the move cap and the
movement test. Kept apart from the Python side of the solver, which sets up and
factors the system.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _solve_inplace(cb, R, zc, cidx, ccoef, cM, crange, starts, frozen, node_contour):
    """Solve A X = R in place for the two columns of R (banded Cholesky + cyclic fix).

    A is block diagonal, one block a contour (``starts``): the substitution chains of
    the contours and of the two columns are independent, and are run interleaved so
    that each division's latency is hidden behind the others (1.7x faster than one
    chain after the other, the very same numbers). The blocks of ``frozen`` contours
    are left as they are.
    """
    K = starts.shape[0] - 1
    longest = 0
    for k in range(K):
        longest = max(longest, starts[k + 1] - starts[k])
    # forward: U^T z = r
    for jj in range(longest):
        for k in range(K):
            j = starts[k] + jj
            if j >= starts[k + 1] or frozen[k]:
                continue
            s0 = R[j, 0]
            s1 = R[j, 1]
            if jj >= 1:
                s0 -= cb[1, j] * R[j - 1, 0]
                s1 -= cb[1, j] * R[j - 1, 1]
            if jj >= 2:
                s0 -= cb[0, j] * R[j - 2, 0]
                s1 -= cb[0, j] * R[j - 2, 1]
            R[j, 0] = s0 / cb[2, j]
            R[j, 1] = s1 / cb[2, j]
    # back: U x = z
    for jj in range(longest):
        for k in range(K):
            i = starts[k + 1] - 1 - jj
            if i < starts[k] or frozen[k]:
                continue
            s0 = R[i, 0]
            s1 = R[i, 1]
            if i + 1 < starts[k + 1]:
                s0 -= cb[1, i + 1] * R[i + 1, 0]
                s1 -= cb[1, i + 1] * R[i + 1, 1]
            if i + 2 < starts[k + 1]:
                s0 -= cb[0, i + 2] * R[i + 2, 0]
                s1 -= cb[0, i + 2] * R[i + 2, 1]
            R[i, 0] = s0 / cb[2, i]
            R[i, 1] = s1 / cb[2, i]
    for c in range(2):
        # low-rank (Woodbury) corrections of closed contours
        for k in range(cidx.shape[0]):
            if frozen[node_contour[crange[k, 0]]]:
                continue
            g0 = 0.0
            g1 = 0.0
            g2 = 0.0
            for m in range(3):
                g0 += ccoef[k, 0, m] * R[cidx[k, 0, m], c]
                g1 += ccoef[k, 1, m] * R[cidx[k, 1, m], c]
                g2 += ccoef[k, 2, m] * R[cidx[k, 2, m], c]
            h0 = cM[k, 0, 0] * g0 + cM[k, 0, 1] * g1 + cM[k, 0, 2] * g2
            h1 = cM[k, 1, 0] * g0 + cM[k, 1, 1] * g1 + cM[k, 1, 2] * g2
            h2 = cM[k, 2, 0] * g0 + cM[k, 2, 1] * g1 + cM[k, 2, 2] * g2
            for i in range(crange[k, 0], crange[k, 1]):
                R[i, c] -= zc[i, 0] * h0 + zc[i, 1] * h1 + zc[i, 2] * h2


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _first_outside(X, fidx, fgeom, frozen, node_contour):
    """The first node outside its field (``fgeom`` rows: x, y of the field's [0, 0],
    its height and width), or -1: the test of ``ContourSystem.outside_fields`` without
    its temporary arrays. Nodes of ``frozen`` contours read no field."""
    for i in range(X.shape[0]):
        if frozen[node_contour[i]]:
            continue
        k = fidx[i]
        x = X[i, 0] - fgeom[k, 0]
        y = X[i, 1] - fgeom[k, 1]
        if x < 0 or y < 0 or x > fgeom[k, 3] - 1 or y > fgeom[k, 2] - 1:
            return i
    return -1


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _pgrad(P, k, y, x, h, w):
    """-grad P at pixel (y, x) of field k: central differences, one-sided at borders."""
    x0 = x - 1 if x > 0 else 0
    x1 = x + 1 if x < w - 1 else w - 1
    y0 = y - 1 if y > 0 else 0
    y1 = y + 1 if y < h - 1 else h - 1
    gx = (P[k, y, x1] - P[k, y, x0]) / (x1 - x0)
    gy = (P[k, y1, x] - P[k, y0, x]) / (y1 - y0)
    return -gx, -gy


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _relax_kernel(X, rest, nxt, a_s, nu_s, p_n, fidx, user, kappa, anchor, node_contour,
                  cb, zc, cidx, ccoef, cM, crange, fields, fgeom, from_potential, gdt, dt,
                  tol, min_iter, max_iter, outside, split, max_step, prv, normal_only,
                  use_rms, starts, each, frozen):
    n = X.shape[0]
    K = starts.shape[0] - 1
    R = np.empty((n, 2))
    # a contour done moves no more: the frozen ones from the start (they keep their nodes
    # and rest lengths, read no field and are not solved), with 'each' those that settle
    done = frozen.copy()
    cmove = np.zeros(K)
    it = 0
    move = np.inf
    rms = np.inf
    while it < max_iter:
        # right-hand side: gamma/dt x + p F(x) + f_user + anchors
        for i in range(n):
            if frozen[node_contour[i]]:
                continue
            fx = 0.0
            fy = 0.0
            k = fidx[i]
            xf = X[i, 0] - fgeom[k, 0]
            yf = X[i, 1] - fgeom[k, 1]
            H = int(fgeom[k, 2])
            W = int(fgeom[k, 3])
            if xf >= 0.0 and yf >= 0.0 and xf <= W - 1 and yf <= H - 1:
                x0 = int(xf)
                y0 = int(yf)
                if x0 > W - 2:
                    x0 = W - 2
                if y0 > H - 2:
                    y0 = H - 2
                tx = xf - x0
                ty = yf - y0
                w00 = (1.0 - tx) * (1.0 - ty)
                w01 = tx * (1.0 - ty)
                w10 = (1.0 - tx) * ty
                w11 = tx * ty
                if from_potential and 1 <= x0 <= W - 3 and 1 <= y0 <= H - 3:
                    # away from the field's border: the twelve pixels around the cell,
                    # read once, with _pgrad's arithmetic (the same numbers, 1.25x
                    # faster a step than four _pgrad calls)
                    p01 = fields[k, y0 - 1, x0]
                    p02 = fields[k, y0 - 1, x0 + 1]
                    p10 = fields[k, y0, x0 - 1]
                    p11 = fields[k, y0, x0]
                    p12 = fields[k, y0, x0 + 1]
                    p13 = fields[k, y0, x0 + 2]
                    p20 = fields[k, y0 + 1, x0 - 1]
                    p21 = fields[k, y0 + 1, x0]
                    p22 = fields[k, y0 + 1, x0 + 1]
                    p23 = fields[k, y0 + 1, x0 + 2]
                    p31 = fields[k, y0 + 2, x0]
                    p32 = fields[k, y0 + 2, x0 + 1]
                    fx = (w00 * -((p12 - p10) / 2) + w01 * -((p13 - p11) / 2)
                          + w10 * -((p22 - p20) / 2) + w11 * -((p23 - p21) / 2))
                    fy = (w00 * -((p21 - p01) / 2) + w01 * -((p22 - p02) / 2)
                          + w10 * -((p31 - p11) / 2) + w11 * -((p32 - p12) / 2))
                elif from_potential:
                    a0, b0 = _pgrad(fields, k, y0, x0, H, W)
                    a1, b1 = _pgrad(fields, k, y0, x0 + 1, H, W)
                    a2, b2 = _pgrad(fields, k, y0 + 1, x0, H, W)
                    a3, b3 = _pgrad(fields, k, y0 + 1, x0 + 1, H, W)
                    fx = w00 * a0 + w01 * a1 + w10 * a2 + w11 * a3
                    fy = w00 * b0 + w01 * b1 + w10 * b2 + w11 * b3
                else:
                    fx = (w00 * fields[k, y0, 2 * x0] + w01 * fields[k, y0, 2 * x0 + 2]
                          + w10 * fields[k, y0 + 1, 2 * x0]
                          + w11 * fields[k, y0 + 1, 2 * x0 + 2])
                    fy = (w00 * fields[k, y0, 2 * x0 + 1] + w01 * fields[k, y0, 2 * x0 + 3]
                          + w10 * fields[k, y0 + 1, 2 * x0 + 1]
                          + w11 * fields[k, y0 + 1, 2 * x0 + 3])
            else:
                outside[node_contour[i]] = True
            if normal_only[i]:
                # drop the component along the contour (tangent from the neighbours)
                ia = prv[i] if prv[i] >= 0 else i
                ib = nxt[i] if nxt[i] >= 0 else i
                tx = X[ib, 0] - X[ia, 0]
                ty = X[ib, 1] - X[ia, 1]
                tl = tx * tx + ty * ty
                if tl > 1e-18:
                    d = (fx * tx + fy * ty) / tl
                    fx -= d * tx
                    fy -= d * ty
            R[i, 0] = gdt * X[i, 0] + p_n[i] * fx + user[i, 0] + kappa[i] * anchor[i, 0]
            R[i, 1] = gdt * X[i, 1] + p_n[i] * fy + user[i, 1] + kappa[i] * anchor[i, 1]
        # explicit tension (eq. 7) and viscoelastic rest lengths (eq. 8)
        for i in range(n):
            j = nxt[i]
            if j < 0 or a_s[i] == 0.0 or frozen[node_contour[i]]:
                continue
            rx = X[j, 0] - X[i, 0]
            ry = X[j, 1] - X[i, 1]
            L = np.sqrt(rx * rx + ry * ry)
            e = L - rest[i]
            if L > 1e-12:
                # explicit: a e r/|r|; split: only -a l r/|r| (a r is in the matrix)
                s = a_s[i] * (-rest[i] if split else e) / L
                R[i, 0] += s * rx
                R[i, 1] += s * ry
                R[j, 0] -= s * rx
                R[j, 1] -= s * ry
            rest[i] += dt * nu_s[i] * e
            if rest[i] < 0.0:
                rest[i] = 0.0
        _solve_inplace(cb, R, zc, cidx, ccoef, cM, crange, starts, frozen, node_contour)
        move2 = 0.0
        sum2 = 0.0
        if each:
            cmove[:] = 0.0
        for i in range(n):
            if done[node_contour[i]]:
                continue
            dx = R[i, 0] - X[i, 0]
            dy = R[i, 1] - X[i, 1]
            d2 = dx * dx + dy * dy
            if max_step > 0.0 and d2 > max_step * max_step:
                f = max_step / np.sqrt(d2)
                R[i, 0] = X[i, 0] + f * dx
                R[i, 1] = X[i, 1] + f * dy
                d2 = max_step * max_step
            sum2 += d2
            if d2 > move2:
                move2 = d2
            if each and d2 > cmove[node_contour[i]]:
                cmove[node_contour[i]] = d2
            X[i, 0] = R[i, 0]
            X[i, 1] = R[i, 1]
        move = np.sqrt(move2)
        # frozen nodes count as nodes that did not move
        rms = np.sqrt(sum2 / n)
        it += 1
        if each:
            # a contour stops at its own equilibrium, not when the slowest one does
            if it >= min_iter:
                left = 0
                for k in range(K):
                    if not done[k]:
                        if cmove[k] < tol * tol:
                            done[k] = True
                        else:
                            left += 1
                if left == 0:
                    break
        elif it >= min_iter and (rms if use_rms else move) < tol:
            break
        if not np.isfinite(move):
            break
    return it, move, rms
