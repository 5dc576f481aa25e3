"""The compiled L-BFGS loop that finds the lattice's equilibrium.

:class:`~synth.integrators.EquilibriumSolver` sets the problem up in Python and runs
the whole minimisation in :func:`_lbfgs_kernel`: two-loop recursion preconditioned by a
sparse ``L D L^T`` factor of the lattice's stiffness (:func:`_ldl_solve3`), a backtracking
line search on the total energy of :mod:`synth.forces`, and restarts on false
convergence. The vector arithmetic is written in LLVM IR (Numba intrinsics) so that its
partial sums are reproducible bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir as llvm_ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from .forces import _total_kernel

#: independent vector accumulators of :func:`_row_dot4` (hides the latency of the adds)
_ROW_ACC = 4


@intrinsic
def _row_dot4(typingctx, work, idx, val, start, stop):  # pragma: no cover
    """``sum(val[k] * work[idx[k], 0:4] for k in range(start, stop))`` as a tuple of four
    floats, computed with 4-wide vector arithmetic (``work`` is C-contiguous ``(n, 4)``
    float64; one vector load per term instead of three scalar ones).  Numba does not
    vectorise the three components of a row by itself, hence the LLVM IR.  Terms go
    round-robin to ``_ROW_ACC`` accumulators, summed pairwise at the end."""
    sig = types.UniTuple(types.float64, 4)(work, idx, val, start, stop)

    def codegen(context, builder, signature, args):
        work_v, idx_v, val_v, start_v, stop_v = args
        wary = context.make_array(signature.args[0])(context, builder, work_v)
        iary = context.make_array(signature.args[1])(context, builder, idx_v)
        vary = context.make_array(signature.args[2])(context, builder, val_v)
        f64 = llvm_ir.DoubleType()
        i32 = llvm_ir.IntType(32)
        i64 = llvm_ir.IntType(64)
        vec = llvm_ir.VectorType(f64, 4)
        rows = builder.bitcast(wary.data, vec.as_pointer())
        undef = llvm_ir.Constant(vec, llvm_ir.Undefined)
        splat = llvm_ir.Constant(llvm_ir.VectorType(i32, 4), [0, 0, 0, 0])
        accs = [cgutils.alloca_once_value(builder, llvm_ir.Constant(vec, [0.0] * 4))
                for _ in range(_ROW_ACC)]
        kptr = cgutils.alloca_once_value(builder, start_v)

        def term(k):
            j = builder.load(builder.gep(iary.data, [k]))
            if j.type.width < 64:
                j = builder.zext(j, i64)          # unsigned indices (uint16)
            v = builder.load(builder.gep(vary.data, [k]))
            if v.type != f64:
                v = builder.fpext(v, f64)
            v = builder.shuffle_vector(builder.insert_element(undef, v, llvm_ir.Constant(i32, 0)),
                                       undef, splat)
            return builder.fmul(v, builder.load(builder.gep(rows, [j]), align=8))

        def add(acc, k):
            builder.store(builder.fadd(builder.load(acc), term(k)), acc)

        main_cond = builder.append_basic_block("rowdot.cond")
        main_body = builder.append_basic_block("rowdot.body")
        tail_cond = builder.append_basic_block("rowdot.tail_cond")
        tail_body = builder.append_basic_block("rowdot.tail_body")
        done = builder.append_basic_block("rowdot.done")
        builder.branch(main_cond)
        builder.position_at_end(main_cond)
        k = builder.load(kptr)
        unroll = llvm_ir.Constant(i64, _ROW_ACC)
        builder.cbranch(builder.icmp_signed("<=", builder.add(k, unroll), stop_v),
                        main_body, tail_cond)
        builder.position_at_end(main_body)
        k = builder.load(kptr)
        for u in range(_ROW_ACC):
            add(accs[u], builder.add(k, llvm_ir.Constant(i64, u)))
        builder.store(builder.add(k, unroll), kptr)
        builder.branch(main_cond)
        builder.position_at_end(tail_cond)
        k = builder.load(kptr)
        builder.cbranch(builder.icmp_signed("<", k, stop_v), tail_body, done)
        builder.position_at_end(tail_body)
        k = builder.load(kptr)
        add(accs[0], k)
        builder.store(builder.add(k, llvm_ir.Constant(i64, 1)), kptr)
        builder.branch(tail_cond)
        builder.position_at_end(done)
        sums = [builder.load(a) for a in accs]
        while len(sums) > 1:
            sums = [builder.fadd(sums[i], sums[i + 1]) for i in range(0, len(sums), 2)]
        out = [builder.extract_element(sums[0], llvm_ir.Constant(i32, c)) for c in range(4)]
        return context.make_tuple(builder, signature.return_type, out)

    return sig, codegen


@numba.njit(cache=True, nogil=True)
def _ldl_solve3(q, rp, rj, rv, lp, li, lx, dinv, perm, work, out):  # pragma: no cover
    """Solve A z = q for 3 right-hand sides (rows of q are nodes) with a symmetric factor
    ``P A P^T = L D L^T``: the strictly lower part of ``L`` by rows (``rp``, ``rj``, ``rv``)
    for the forward sweep and by columns (``lp``, ``li``, ``lx``) for the backward one, so
    both sweeps gather (dot products, no scattered stores); ``dinv = 1 / diag(D)``; row ``i``
    of ``A`` is row ``perm[i]`` of the factor.  ``work`` is ``(n, 4)`` (C order): a padded
    row is one vector load in :func:`_row_dot4`."""
    n = q.shape[0]
    if work.shape[0] < n or work.shape[1] != 4:
        raise ValueError("_ldl_solve3: work must have shape (n, 4)")
    for i in range(n):
        r = perm[i]
        work[r, 0] = q[i, 0]
        work[r, 1] = q[i, 1]
        work[r, 2] = q[i, 2]
        work[r, 3] = 0.0
    for i in range(n):
        a0, a1, a2, _ = _row_dot4(work, rj, rv, rp[i], rp[i + 1])
        work[i, 0] -= a0
        work[i, 1] -= a1
        work[i, 2] -= a2
    for j in range(n - 1, -1, -1):
        a0, a1, a2, _ = _row_dot4(work, li, lx, lp[j], lp[j + 1])
        d = dinv[j]
        work[j, 0] = work[j, 0] * d - a0
        work[j, 1] = work[j, 1] * d - a1
        work[j, 2] = work[j, 2] * d - a2
    for i in range(n):
        r = perm[i]
        out[i, 0] = work[r, 0]
        out[i, 1] = work[r, 1]
        out[i, 2] = work[r, 2]


def _lanes4(builder, ptr, i, f64):  # pragma: no cover
    """``<4 x double>`` from ``ptr[i:i + 4]`` (float or double elements)."""
    elt = ptr.type.pointee
    vp = builder.bitcast(builder.gep(ptr, [i]), llvm_ir.VectorType(elt, 4).as_pointer())
    v = builder.load(vp, align=4 if elt != f64 else 8)
    if elt != f64:
        v = builder.fpext(v, llvm_ir.VectorType(f64, 4))
    return v


def _scalar(builder, ptr, i, f64):  # pragma: no cover
    v = builder.load(builder.gep(ptr, [i]))
    return v if v.type == f64 else builder.fpext(v, f64)


def _dot_codegen(axpy):  # pragma: no cover
    """LLVM IR of :func:`_dot` / :func:`_axpy_dot`: 4-wide vector loop, lane ``k`` holding
    the partial sum of the elements ``i = k (mod 4)``, the ``n % 4`` last ones added to lane
    0, result ``(d0 + d1) + (d2 + d3)``: the four partial sums of a scalar loop, bit for bit,
    whatever the alignment of the arrays (no reassociation flags)."""
    def codegen(context, builder, signature, args):
        f64 = llvm_ir.DoubleType()
        i64 = llvm_ir.IntType(64)
        i32 = llvm_ir.IntType(32)
        vec = llvm_ir.VectorType(f64, 4)
        if axpy:
            x_v, c_v, u_v, w_v = args
            xt, _, ut, wt = signature.args
            xa = context.make_array(xt)(context, builder, x_v)
            ua = context.make_array(ut)(context, builder, u_v)
            wa = context.make_array(wt)(context, builder, w_v)
            n = cgutils.unpack_tuple(builder, xa.shape)[0]
            cvec = builder.shuffle_vector(
                builder.insert_element(llvm_ir.Constant(vec, llvm_ir.Undefined), c_v,
                                       llvm_ir.Constant(i32, 0)),
                llvm_ir.Constant(vec, llvm_ir.Undefined),
                llvm_ir.Constant(llvm_ir.VectorType(i32, 4), [0, 0, 0, 0]))
        else:
            a_v, b_v = args
            at, bt = signature.args
            aa = context.make_array(at)(context, builder, a_v)
            ba = context.make_array(bt)(context, builder, b_v)
            n = cgutils.unpack_tuple(builder, aa.shape)[0]
        acc = cgutils.alloca_once_value(builder, llvm_ir.Constant(vec, [0.0] * 4))
        kptr = cgutils.alloca_once_value(builder, llvm_ir.Constant(i64, 0))
        four = llvm_ir.Constant(i64, 4)
        bb_cond = builder.append_basic_block("vd.cond")
        bb_body = builder.append_basic_block("vd.body")
        bb_tcond = builder.append_basic_block("vd.tcond")
        bb_tbody = builder.append_basic_block("vd.tbody")
        bb_tguard = builder.append_basic_block("vd.tguard")
        bb_done = builder.append_basic_block("vd.done")
        d0 = cgutils.alloca_once_value(builder, llvm_ir.Constant(f64, 0.0))
        builder.branch(bb_cond)
        builder.position_at_end(bb_cond)
        k = builder.load(kptr)
        builder.cbranch(builder.icmp_signed("<=", builder.add(k, four), n), bb_body, bb_tcond)
        builder.position_at_end(bb_body)
        k = builder.load(kptr)
        if axpy:
            xp = builder.bitcast(builder.gep(xa.data, [k]), vec.as_pointer())
            v = builder.fadd(builder.load(xp, align=8),
                             builder.fmul(cvec, _lanes4(builder, ua.data, k, f64)))
            builder.store(v, xp, align=8)
            t = builder.fmul(_lanes4(builder, wa.data, k, f64), v)
        else:
            t = builder.fmul(_lanes4(builder, aa.data, k, f64), _lanes4(builder, ba.data, k, f64))
        builder.store(builder.fadd(builder.load(acc), t), acc)
        builder.store(builder.add(k, four), kptr)
        builder.branch(bb_cond)
        # remainder (n % 4 elements) into the first partial sum
        builder.position_at_end(bb_tcond)
        lanes = builder.load(acc)
        builder.store(builder.extract_element(lanes, llvm_ir.Constant(i32, 0)), d0)
        builder.branch(bb_tguard)
        builder.position_at_end(bb_tguard)
        k = builder.load(kptr)
        builder.cbranch(builder.icmp_signed("<", k, n), bb_tbody, bb_done)
        builder.position_at_end(bb_tbody)
        k = builder.load(kptr)
        if axpy:
            xp = builder.gep(xa.data, [k])
            v = builder.fadd(builder.load(xp), builder.fmul(c_v, _scalar(builder, ua.data, k, f64)))
            builder.store(v, xp)
            t = builder.fmul(_scalar(builder, wa.data, k, f64), v)
        else:
            t = builder.fmul(_scalar(builder, aa.data, k, f64), _scalar(builder, ba.data, k, f64))
        builder.store(builder.fadd(builder.load(d0), t), d0)
        builder.store(builder.add(k, llvm_ir.Constant(i64, 1)), kptr)
        builder.branch(bb_tguard)
        builder.position_at_end(bb_done)
        e = [builder.extract_element(lanes, llvm_ir.Constant(i32, c)) for c in range(4)]
        return builder.fadd(builder.fadd(builder.load(d0), e[1]), builder.fadd(e[2], e[3]))
    return codegen


@intrinsic
def _dot(typingctx, a, b):  # pragma: no cover
    """``a . b`` (1-D contiguous float32 / float64 arrays of equal length) in double
    precision with four interleaved partial sums, vectorised (see :func:`_dot_codegen`)."""
    return types.float64(a, b), _dot_codegen(False)


@intrinsic
def _axpy_dot(typingctx, x, c, u, w):  # pragma: no cover
    """``x += c u`` in place (``x`` float64), then return ``w . x``; one vectorised pass,
    four partial sums (see :func:`_dot_codegen`)."""
    return types.float64(x, c, u, w), _dot_codegen(True)


#: a converged L-BFGS step is double-checked against the preconditioned gradient step, which
#: must then be below this many times the tolerance (it is shorter than the quasi-Newton step
#: near a minimum: ``A`` over-stiffens the soft modes)
_RESTART_RATIO = 4.0


@numba.njit(cache=True, nogil=True)
def _lbfgs_kernel(x, free, forces_args, factor, s_hist, y_hist, rho, state, tol,
                  max_iter):  # pragma: no cover
    """Minimise the lattice energy over the free nodes, in place on ``x``.

    ``state`` = [n_pairs, head] of the ring buffer of curvature pairs (updated).
    Returns (iterations, last step, energy, status) with status 0 = converged,
    1 = iteration cap, 2 = non-finite energy / line search failure, 3 = stopped at the
    floating-point floor of the energy (converged as far as arithmetic allows)."""
    (springs, rest_length, k_low, k_high, switch, prisms, quads, rest_volume, bulk,
     use_volume, sk_nodes, sk_bone, sk_normal, sk_margin, sk_k, c_pairs, c_normal, c_k,
     f_ext, fixed) = forces_args
    rp, rj, rv, lp, li, lx, dinv, perm = factor
    nf = free.shape[0]
    m = s_hist.shape[0]
    fbuf = np.empty_like(x)
    g = np.empty((nf, 3))
    gn = np.empty((nf, 3))
    q = np.empty((nf, 3))
    z = np.empty((nf, 3))
    work = np.empty((nf, 4))
    xf = np.empty((nf, 3))
    alphas = np.empty(m)
    n3 = 3 * nf
    s2 = s_hist.reshape((m, n3))
    y2 = y_hist.reshape((m, n3))
    gf = g.reshape(n3)
    qf = q.reshape(n3)
    zf = z.reshape(n3)
    energy = _total_kernel(x, springs, rest_length, k_low, k_high, switch, prisms, quads,
                           rest_volume, bulk, use_volume, sk_nodes, sk_bone, sk_normal,
                           sk_margin, sk_k, c_pairs, c_normal, c_k, f_ext, fixed, fbuf)
    for a in range(nf):
        for c in range(3):
            g[a, c] = -fbuf[free[a], c]
    it = 0
    step = np.inf
    status = 0
    while True:
        n_pairs = state[0]
        head = state[1]
        # two-loop recursion, newest pair first; H0 = A^{-1}.  Flat views; each pass over a
        # pair's vectors also takes the dot product the next pair needs.
        for i in range(n3):
            qf[i] = gf[i]
        dot = 0.0
        if n_pairs > 0:
            dot = _dot(s2[(head - 1) % m], qf)
        for t in range(n_pairs):
            k = (head - 1 - t) % m
            ak = rho[k] * dot
            alphas[t] = ak
            # q -= ak y_k, and the next (older) pair's s . q in the same pass
            dot = _axpy_dot(qf, -ak, y2[k], s2[(head - 2 - t) % m])
        _ldl_solve3(q, rp, rj, rv, lp, li, lx, dinv, perm, work, z)
        dot = 0.0
        if n_pairs > 0:
            dot = _dot(y2[(head - n_pairs) % m], zf)
        for t in range(n_pairs - 1, -1, -1):
            k = (head - 1 - t) % m
            coef = alphas[t] - rho[k] * dot
            # z += coef s_k, and the next (newer) pair's y . z in the same pass
            dot = _axpy_dot(zf, coef, s2[k], y2[(head - t) % m])
        slope = -_dot(gf, zf)                        # p = -z
        if slope >= 0.0:
            state[0] = 0
            _ldl_solve3(g, rp, rj, rv, lp, li, lx, dinv, perm, work, z)
            slope = -_dot(gf, zf)
        step = 0.0
        for a in range(nf):
            for c in range(3):
                v = abs(z[a, c])
                if v > step:
                    step = v
        if step <= tol and state[0] > 0:
            # a short quasi-Newton step can also come from poor curvature pairs (a false
            # convergence, seen after lip / skull contact changes): accept it only if the plain
            # preconditioned step A^{-1} g is short too, else restart the pairs from that step
            _ldl_solve3(g, rp, rj, rv, lp, li, lx, dinv, perm, work, z)
            step0 = 0.0
            slope = 0.0
            for i in range(n3):
                v = abs(zf[i])
                if v > step0:
                    step0 = v
                slope -= gf[i] * zf[i]
            if step0 > _RESTART_RATIO * tol:
                state[0] = 0
                step = step0
        if step <= tol:
            break
        it += 1
        if it > max_iter:
            status = 1
            break
        for a in range(nf):
            for c in range(3):
                xf[a, c] = x[free[a], c]
        alpha = 1.0
        ok = False
        en = energy
        for _ in range(30):
            for a in range(nf):
                for c in range(3):
                    x[free[a], c] = xf[a, c] - alpha * z[a, c]
            en = _total_kernel(x, springs, rest_length, k_low, k_high, switch, prisms, quads,
                               rest_volume, bulk, use_volume, sk_nodes, sk_bone, sk_normal,
                               sk_margin, sk_k, c_pairs, c_normal, c_k, f_ext, fixed, fbuf)
            if np.isfinite(en) and en <= energy + 1e-4 * alpha * slope:
                ok = True
                break
            alpha *= 0.5
        if not ok:
            for a in range(nf):
                for c in range(3):
                    x[free[a], c] = xf[a, c]
            # no decrease found: either the energy is at its floating-point floor (the
            # expected decrease is below round-off; converged) or something went wrong
            if -slope <= 1e-11 * (abs(energy) + 1.0) and np.isfinite(energy):
                status = 3
            else:
                status = 2
            break
        for a in range(nf):
            for c in range(3):
                gn[a, c] = -fbuf[free[a], c]
        # curvature pair s = alpha p = -alpha z, y = gn - g; a pair with too little
        # curvature is skipped (and must not overwrite the oldest pair kept in the ring)
        gnf = gn.reshape(n3)
        sy = 0.0
        yy = 0.0
        for i in range(n3):
            sv = -alpha * zf[i]
            yv = gnf[i] - gf[i]
            sy += sv * yv
            yy += yv * yv
        if m > 0 and sy > 1e-12 * yy:
            # stored in the precision of the history buffers; rho from the stored values
            k = state[1]
            sy = 0.0
            for i in range(n3):
                s2[k, i] = -alpha * zf[i]
                y2[k, i] = gnf[i] - gf[i]
                sy += np.float64(s2[k, i]) * np.float64(y2[k, i])
            if sy > 0.0:
                rho[k] = 1.0 / sy
                state[1] = (k + 1) % m
                if state[0] < m:
                    state[0] += 1
        for a in range(nf):
            for c in range(3):
                g[a, c] = gn[a, c]
        energy = en
    return it, step, energy, status
