"""Explicit vector code for the rows of the compiled passes (numba intrinsics).

numba hands its functions to LLVM with the loop vectoriser on and the SLP vectoriser off.
Rows of the netsense passes are short (``n = 10`` coordinates, ``M = 5`` substates at the
benchmark's smallest shape), and a short loop runs mostly in the scalar remainder the
loop vectoriser leaves after its wide body. The helpers here write the vector code
directly, with LLVM vector types, masked loads and masked stores (one vector register per
:data:`VECTOR_BYTES`; LLVM splits them on narrower hardware), and keep the scalar
semantics exactly: every output element is computed by the same IEEE operations in the
same order as the scalar loop they replace, so results are bit-identical to it wherever
a row runs (``tests/test_lanes.py`` holds them to scalar references).

They are inlined into the drivers (:mod:`netsense.kernels.drivers`,
:mod:`netsense.engine.observation`),
mostly through the row functions of :mod:`netsense.kernels.rules`; this file is part of the drivers'
cache key (:func:`netsense.kernels.jit.inlined_digest`). There is no bounds check: the
callers check the shapes.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types as nbtypes
from numba.core import cgutils
from numba.core.extending import intrinsic

__all__ = ["VECTOR_BYTES", "block_triangular_pair", "block_triangular_row", "copy_span",
           "row_times_matrix", "square_sums"]

#: Bytes of one vector (AVX-512: 8 float64 or 16 float32).
VECTOR_BYTES = 64
_F64_LANES = VECTOR_BYTES // 8
_MAX_ACC = 4  # vector accumulators per pass over the columns of block_triangular_row

_I32 = ir.IntType(32)


def _c_array(t, ndim: int | None = None, dtype=None) -> bool:
    """``t`` is a C-contiguous array type (of ``ndim`` dimensions and ``dtype``, if given)."""
    return (isinstance(t, nbtypes.Array) and t.layout == "C"
            and (ndim is None or t.ndim == ndim) and (dtype is None or t.dtype == dtype))


def _pointer(context, builder, aryty, ary, index):
    """Pointer to ``ary[index]`` (all axes indexed) and the array's shape."""
    arr = context.make_array(aryty)(context, builder, ary)
    shape = cgutils.unpack_tuple(builder, arr.shape)
    strides = cgutils.unpack_tuple(builder, arr.strides)
    return cgutils.get_item_pointer2(context, builder, arr.data, shape, strides,
                                     aryty.layout, index, wraparound=False), shape


def _splat(builder, value, lanes: int):
    t = ir.VectorType(value.type, lanes)
    u = builder.insert_element(ir.Constant(t, ir.Undefined), value, _I32(0))
    return builder.shuffle_vector(u, ir.Constant(t, ir.Undefined),
                                  ir.Constant(ir.VectorType(_I32, lanes), [0] * lanes))


def _masked(builder, vec, ptr_type):
    """``llvm.masked.load`` and ``llvm.masked.store`` for the vector type ``vec``."""
    lanes, elem = vec.count, vec.element
    bits = ir.VectorType(ir.IntType(1), lanes)
    name = {"double": "f64", "float": "f32"}.get(str(elem), str(elem))  # i8, i16, ...
    suffix = f"v{lanes}{name}.p0"
    load = cgutils.get_or_insert_function(
        builder.module, ir.FunctionType(vec, [ptr_type, _I32, bits, vec]),
        f"llvm.masked.load.{suffix}")
    store = cgutils.get_or_insert_function(
        builder.module, ir.FunctionType(ir.VoidType(), [vec, ptr_type, _I32, bits]),
        f"llvm.masked.store.{suffix}")
    return load, store


def _first(builder, intp, lanes: int, count):
    """The mask of the first ``count`` lanes (all of them when ``count >= lanes``)."""
    lane = ir.Constant(ir.VectorType(intp, lanes), list(range(lanes)))
    return builder.icmp_signed("<", lane, _splat(builder, count, lanes))


@intrinsic
def block_triangular_row(typingctx, out, ob, oi, Z_sel, sb, si, A_diag_T, Z, b, i,
                         A_lower_T):
    """``out[ob, oi] = z_sel A_diag^T + z A_lower^T`` for the rows ``z_sel = Z_sel[sb, si]``
    and ``z = Z[b, i]`` (eqs. (7), (10), (12)).

    The order, the same for every output column ``c``: start from ``0.0``; add
    ``A_diag_T[q, c] * z_sel[q]`` for ``q = 0 .. n-1`` where ``A_diag_T[q, c] != 0`` (the
    block diagonal's non-zeros only, so a non-finite ``z_sel[q]`` outside ``c``'s block
    does not reach ``c``); then add ``A_lower_T[q, c] * z[q]`` for ``q = 0 .. n-1``. Each
    term is a multiply and then an add, never fused. That is the scalar loop
    ``o[c] += a * v`` in the same order; the lanes only compute columns side by side.

    The columns are taken in passes of up to ``4 x 8``, held in as few vector
    accumulators as the pass needs; the row's end is handled by masked loads and stores.
    All arrays are C-contiguous float64 with ``n = out.shape[2]`` columns, ``A_*_T`` of
    shape ``(n, n)``.
    """
    return _block_triangular(1, out, ob, oi, Z_sel, sb, si, A_diag_T, Z, b, i, A_lower_T)


@intrinsic
def block_triangular_pair(typingctx, out, ob, oi, Z_sel, sb, si, A_diag_T, Z, b, i,
                          A_lower_T):
    """:func:`block_triangular_row` for two consecutive rows at once: ``out[ob, oi + h]``
    from ``Z_sel[sb, si + h]`` and ``Z[b, i + h]``, ``h = 0, 1``.

    Each row is computed exactly as :func:`block_triangular_row` computes it (the same
    operations in the same order, bit for bit); the two rows share the loads of the
    matrices and run in one loop, so their chains of adds (``2 n`` long per column)
    overlap instead of following each other (measured 0.18 -> 0.12 ms for the 10,240
    rows of ``(B, N, n) = (1024, 10, 10)``, one thread). No bounds check: the caller
    guarantees that the row ``+ 1`` exists in each array.
    """
    return _block_triangular(2, out, ob, oi, Z_sel, sb, si, A_diag_T, Z, b, i, A_lower_T)


def _block_triangular(R, out, ob, oi, Z_sel, sb, si, A_diag_T, Z, b, i, A_lower_T):
    """Signature and code of ``R`` consecutive rows of :func:`block_triangular_row`."""
    f64 = nbtypes.float64
    if not (_c_array(out, 3, f64) and _c_array(Z_sel, 3, f64) and _c_array(Z, 3, f64)
            and _c_array(A_diag_T, 2, f64) and _c_array(A_lower_T, 2, f64)
            and all(isinstance(t, nbtypes.Integer) for t in (ob, oi, sb, si, b, i))):
        return None  # a typing error: C-contiguous float64 arrays, integer indices
    sig = nbtypes.void(out, ob, oi, Z_sel, sb, si, A_diag_T, Z, b, i, A_lower_T)

    def codegen(context, builder, signature, args):
        ts = signature.args
        intp = context.get_value_type(nbtypes.intp)
        zero = intp(0)

        def index(k, h=0):
            return builder.add(context.cast(builder, args[k], ts[k], nbtypes.intp), intp(h))

        d_ptr, _ = _pointer(context, builder, ts[6], args[6], [zero, zero])
        a_ptr, _ = _pointer(context, builder, ts[10], args[10], [zero, zero])
        rows = []
        for h in range(R):
            o_ptr, o_shape = _pointer(context, builder, ts[0], args[0],
                                      [index(1), index(2, h), zero])
            s_ptr, _ = _pointer(context, builder, ts[3], args[3], [index(4), index(5, h), zero])
            z_ptr, _ = _pointer(context, builder, ts[7], args[7], [index(8), index(9, h), zero])
            rows.append((o_ptr, (s_ptr, z_ptr)))
        n = o_shape[2]
        _row_products(builder, intp, rows, n, [(d_ptr, n, True), (a_ptr, n, False)])
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def row_times_matrix(typingctx, out, ob, x, b, A):
    """``out[ob] = x[b] @ A`` for ``x (., p)``, ``A (p, m)`` and ``out (., m)``: each
    column ``c`` starts from ``0.0`` and adds ``x[b, q] * A[q, c]`` for ``q = 0 .. p-1``,
    a multiply and then an add, never fused (the scalar loop of
    :func:`netsense.kernels.rules.vecmat_row`, whose results it reproduces bit for bit; the lanes
    compute columns side by side, in the passes of :func:`block_triangular_row`). All
    arrays are C-contiguous 2-d float64; ``x`` and ``out`` may be one array only if
    ``b != ob``.
    """
    f64 = nbtypes.float64
    if not (_c_array(out, 2, f64) and _c_array(x, 2, f64) and _c_array(A, 2, f64)
            and all(isinstance(t, nbtypes.Integer) for t in (ob, b))):
        return None  # a typing error: C-contiguous 2-d float64 arrays, integer indices
    sig = nbtypes.void(out, ob, x, b, A)

    def codegen(context, builder, signature, args):
        ts = signature.args
        intp = context.get_value_type(nbtypes.intp)
        zero = intp(0)
        o_ptr, o_shape = _pointer(context, builder, ts[0], args[0],
                                  [context.cast(builder, args[1], ts[1], nbtypes.intp), zero])
        x_ptr, _ = _pointer(context, builder, ts[2], args[2],
                            [context.cast(builder, args[3], ts[3], nbtypes.intp), zero])
        a_ptr, a_shape = _pointer(context, builder, ts[4], args[4], [zero, zero])
        _row_products(builder, intp, [(o_ptr, (x_ptr,))], o_shape[1],
                      [(a_ptr, a_shape[0], False)])
        return context.get_dummy_value()

    return sig, codegen


def _row_products(builder, intp, rows, m, terms) -> None:
    """Emit, for every ``(o, vs)`` of ``rows``, ``o[0:m] = sum over t of vs[t] @ A_t``
    with ``terms[t] = (A_t, p_t, nonzero_only_t)``, ``A_t`` a C-contiguous ``(p_t, m)``
    block: from ``0.0``, the terms in the order given, ``q = 0 .. p_t - 1`` ascending in
    each, ``+ vs[t][q] * A_t[q, c]`` as a multiply then an add; ``nonzero_only`` skips
    the entries where ``A_t[q, c] == 0``. The rows share each load of ``A_t`` and run in
    one loop (independent chains of adds). The columns are taken in passes of up to
    ``_MAX_ACC`` vectors of :data:`VECTOR_BYTES`, held in as few accumulators per row as
    the pass needs, the row's end masked."""
    zero, L = intp(0), _F64_LANES
    vec = ir.VectorType(ir.DoubleType(), L)
    load, store = _masked(builder, vec, rows[0][0].type)
    align, zeros = _I32(8), ir.Constant(vec, [0.0] * L)
    acc = [[cgutils.alloca_once(builder, vec) for _ in range(_MAX_ACC)] for _ in rows]

    def columns(s, H):  # one pass: the columns s .. s + H L - 1 that are < m
        left = builder.sub(m, s)
        masks = [_first(builder, intp, L, builder.sub(left, intp(L * h))) for h in range(H)]
        cols = [builder.add(s, intp(L * h)) for h in range(H)]
        for row_acc in acc:
            for h in range(H):
                builder.store(zeros, row_acc[h])
        for t, (m_ptr, p, nonzero_only) in enumerate(terms):
            with cgutils.for_range(builder, p, intp=intp) as loop:
                q = loop.index
                vs = [_splat(builder, builder.load(builder.gep(v_ptrs[t], [q])), L)
                      for _, v_ptrs in rows]
                row = builder.mul(q, m)
                for h in range(H):
                    a = builder.call(load, [builder.gep(m_ptr, [builder.add(row, cols[h])]),
                                            align, masks[h], zeros])
                    keep = builder.fcmp_ordered("!=", a, zeros) if nonzero_only else None
                    for v, row_acc in zip(vs, acc, strict=True):
                        old = builder.load(row_acc[h])
                        new = builder.fadd(old, builder.fmul(a, v))
                        if nonzero_only:
                            new = builder.select(keep, new, old)
                        builder.store(new, row_acc[h])
        for (o_ptr, _), row_acc in zip(rows, acc, strict=True):
            for h in range(H):
                builder.call(store, [builder.load(row_acc[h]), builder.gep(o_ptr, [cols[h]]),
                                     align, masks[h]])

    with cgutils.for_range_slice(builder, zero, m, intp(_MAX_ACC * L), intp=intp) as (s, _):
        left = builder.sub(m, s)

        def fewest(H):  # as few accumulators as the remaining columns need
            if H == _MAX_ACC:
                columns(s, H)
                return
            with builder.if_else(builder.icmp_signed("<=", left, intp(H * L))) as (
                    then, other):
                with then:
                    columns(s, H)
                with other:
                    fewest(H + 1)

        fewest(1)


@intrinsic
def square_sums(typingctx, out, ob, Z, b, t, tb):
    """``out[ob, i] = sum_c (Z[b, i, c] - t[tb, c]) ** 2`` for every row ``i`` of ``Z[b]``
    (``t`` None: ``sum_c Z[b, i, c] ** 2``), each from ``0.0`` with ``c`` ascending, a
    subtract, a multiply and an add per term, never fused: the scalar loop, bit for bit.

    The differences and squares of a row are taken in lanes (masked at the row's end),
    then added lane by lane in column order; the rows' sums are independent chains
    (measured 0.052 -> 0.035 ms for the 1,024 x 10 rows of ``n = 10``, one thread).
    ``Z (., N, n)``, ``out (., >= N)`` and ``t (., n)`` are C-contiguous float64; no
    bounds check.
    """
    f64 = nbtypes.float64
    centred = not isinstance(t, nbtypes.NoneType)
    if not (_c_array(out, 2, f64) and _c_array(Z, 3, f64)
            and (not centred or _c_array(t, 2, f64))
            and all(isinstance(v, nbtypes.Integer) for v in (ob, b, tb))):
        return None  # a typing error: C-contiguous float64 arrays, integer indices
    sig = nbtypes.void(out, ob, Z, b, t, tb)

    def codegen(context, builder, signature, args):
        ts = signature.args
        intp = context.get_value_type(nbtypes.intp)
        zero, L = intp(0), _F64_LANES

        def index(k):
            return context.cast(builder, args[k], ts[k], nbtypes.intp)

        o_ptr, _ = _pointer(context, builder, ts[0], args[0], [index(1), zero])
        z_ptr, z_shape = _pointer(context, builder, ts[2], args[2], [index(3), zero, zero])
        t_ptr = (_pointer(context, builder, ts[4], args[4], [index(5), zero])[0]
                 if centred else None)
        N, n = z_shape[1], z_shape[2]
        vec = ir.VectorType(ir.DoubleType(), L)
        zeros = ir.Constant(vec, [0.0] * L)
        load, _ = _masked(builder, vec, z_ptr.type)
        acc = cgutils.alloca_once(builder, ir.DoubleType())
        with cgutils.for_range(builder, N, intp=intp) as rloop:
            row = builder.gep(z_ptr, [builder.mul(rloop.index, n)])
            builder.store(ir.Constant(ir.DoubleType(), 0.0), acc)
            with cgutils.for_range_slice(builder, zero, n, intp(L), intp=intp) as (c0, _):
                mask = _first(builder, intp, L, builder.sub(n, c0))
                v = builder.call(load, [builder.gep(row, [c0]), _I32(8), mask, zeros])
                if centred:
                    tv = builder.call(load, [builder.gep(t_ptr, [c0]), _I32(8), mask, zeros])
                    v = builder.fsub(v, tv)
                sq = builder.fmul(v, v)
                left = builder.sub(n, c0)

                def add_lanes(count):  # lanes 0 .. count-1 in order (the row's end: fewer)
                    total = builder.load(acc)
                    for h in range(count):
                        total = builder.fadd(total, builder.extract_element(sq, _I32(h)))
                    builder.store(total, acc)

                def tail(h):  # the row ends after lane h (h = L - 1: a full vector)
                    if h == L - 1:
                        add_lanes(L)
                        return
                    with builder.if_else(builder.icmp_signed("==", left, intp(h + 1))) as (
                            then, other):
                        with then:
                            add_lanes(h + 1)
                        with other:
                            tail(h + 1)

                with builder.if_else(builder.icmp_signed(">=", left, intp(L)),
                                     likely=True) as (full, part):
                    with full:
                        add_lanes(L)
                    with part:
                        tail(0)
            builder.store(builder.load(acc), builder.gep(o_ptr, [rloop.index]))
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def copy_span(typingctx, dst, dst_start, src, src_start, count):
    """Copy ``count`` elements from ``src`` to ``dst``, C-contiguous arrays of one dtype
    (1, 2, 4 or 8 bytes) and any dimensions, from the flat (C-order) positions
    ``src_start`` and ``dst_start``: ``dst.reshape(-1)[dst_start:dst_start + count] =
    src.reshape(-1)[src_start:src_start + count]``, one vector (masked at the end) per
    :data:`VECTOR_BYTES`."""
    if not (_c_array(dst) and _c_array(src) and dst.dtype == src.dtype
            and isinstance(dst.dtype, (nbtypes.Integer, nbtypes.Float, nbtypes.Boolean))
            and all(isinstance(t, nbtypes.Integer) for t in (dst_start, src_start, count))):
        return None
    sig = nbtypes.void(dst, dst_start, src, src_start, count)

    def codegen(context, builder, signature, args):
        ts = signature.args
        intp = context.get_value_type(nbtypes.intp)

        def index(k):
            return context.cast(builder, args[k], ts[k], nbtypes.intp)

        d_ptr = builder.gep(context.make_array(ts[0])(context, builder, args[0]).data,
                            [index(1)])
        s_ptr = builder.gep(context.make_array(ts[2])(context, builder, args[2]).data,
                            [index(3)])
        elem = context.get_data_type(ts[0].dtype)
        size = context.get_abi_sizeof(elem)
        L = VECTOR_BYTES // size
        vec = ir.VectorType(elem, L)
        load, store = _masked(builder, vec, d_ptr.type)
        undef = ir.Constant(vec, ir.Undefined)
        count = index(4)
        with cgutils.for_range_slice(builder, intp(0), count, intp(L), intp=intp) as (s, _):
            m = _first(builder, intp, L, builder.sub(count, s))
            v = builder.call(load, [builder.gep(s_ptr, [s]), _I32(size), m, undef])
            builder.call(store, [v, builder.gep(d_ptr, [s]), _I32(size), m])
        return context.get_dummy_value()

    return sig, codegen
