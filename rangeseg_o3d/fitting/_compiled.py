"""Compiled (numba) Levenberg-Marquardt for the sphere and cylinder fits, and the axis search scores.

Levenberg-Marquardt with Marquardt's scaled damping (``diag += damping * (diag + 1e-12)``,
damping x0.1 on an accepted step, x10 on a rejected one). Converged means the step or the
relative cost decrease fell to rounding level (1e-10, 1e-12); a radius beyond
``RADIUS_LIMIT`` times the patch size abandons the run (the points are flat). Each
evaluation forms the normal equations ``J^T J``, ``J^T r`` in one pass over the points
instead of the Jacobian: a fit costs tens of microseconds, not the milliseconds of numpy's
per-call overhead on a few hundred points. Imported on first use (numba compiles and
caches on first call).
"""

from __future__ import annotations

import numpy as np
from ..kernels.jit import njit  # numba.njit, with this package's cache locator installed

from ..kernels.linalg import collinear, hesse_form, solve, solve_in_place
from ._codes import RADIUS_LIMIT

#: Files whose kernels or constants compile into this module's (kernels.cache: an edit there recompiles it).
CACHE_DEPENDS = ("_codes.py", "../kernels/linalg.py")

__all__ = ["sphere_lm", "cylinder_lm", "circle_scores", "cylinder_union_reach", "sphere_union_reach"]


@njit(cache=True, nogil=True, inline="always")
def _symmetrise(m):
    for a in range(m.shape[0]):
        for b in range(a):
            m[a, b] = m[b, a]


@njit(cache=True, nogil=True, inline="always")
def _packed_system(sums, jtj):
    # J^T J (symmetric) into ``jtj`` from its upper triangle packed row by row in ``sums``
    n_params = jtj.shape[0]
    m = 0
    for a in range(n_params):
        for b in range(a, n_params):
            jtj[a, b] = jtj[b, a] = sums[m]
            m += 1


@njit(cache=True, nogil=True)
def _sphere_normal_equations(q, params):
    # (cost, J^T J, J^T r) in new arrays (see _sphere_system)
    jtj, grad = np.empty((4, 4)), np.empty(4)
    return _sphere_system(q, params, jtj, grad), jtj, grad


@njit(cache=True, nogil=True)
def _sphere_system(q, params, jtj, grad):
    # The cost, with J^T J and J^T r written into ``jtj`` (4 x 4) and ``grad`` (4): the
    # Levenberg-Marquardt loop keeps them in two buffers (a few small arrays a step cost
    # it as much as the pass over a few dozen points). Sums kept in scalars: stored into
    # arrays point by point they are not kept in registers. The last Jacobian entry is -1
    # for every point.
    s00 = s01 = s02 = s03 = s11 = s12 = s13 = s22 = s23 = 0.0
    g0 = g1 = g2 = g3 = 0.0
    cost = 0.0
    for i in range(q.shape[0]):
        dx, dy, dz = q[i, 0] - params[0], q[i, 1] - params[1], q[i, 2] - params[2]
        dist = np.sqrt(dx * dx + dy * dy + dz * dz)
        inv = 1.0 / max(dist, 1e-300)
        res = dist - params[3]
        r0, r1, r2 = -dx * inv, -dy * inv, -dz * inv
        cost += res * res
        g0 += r0 * res
        g1 += r1 * res
        g2 += r2 * res
        g3 -= res
        s00 += r0 * r0
        s01 += r0 * r1
        s02 += r0 * r2
        s03 -= r0
        s11 += r1 * r1
        s12 += r1 * r2
        s13 -= r1
        s22 += r2 * r2
        s23 -= r2
    _packed_system((s00, s01, s02, s03, s11, s12, s13, s22, s23, float(q.shape[0])), jtj)
    grad[0], grad[1], grad[2], grad[3] = g0, g1, g2, g3
    return cost


@njit(cache=True, nogil=True)
def _frame(axis):
    # u, v completing a unit axis to a right-handed frame (as cylinder._frame)
    u, v = np.empty(3), np.empty(3)
    _frame_into(axis, u, v)
    return u, v


@njit(cache=True, nogil=True, inline="always")
def _frame_into(axis, u, v):
    # _frame written into ``u`` and ``v``
    x, y, z = axis[0], axis[1], axis[2]
    if abs(x) <= 0.9:
        u[0], u[1], u[2] = 0.0, z, -y
    else:
        u[0], u[1], u[2] = -z, 0.0, x
    u /= np.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
    v[0] = y * u[2] - z * u[1]
    v[1] = z * u[0] - x * u[2]
    v[2] = x * u[1] - y * u[0]


@njit(cache=True, nogil=True)
def _cylinder_normal_equations(q, axis, u, v, p0, r):
    # (cost, J^T J, J^T r) in new arrays (see _cylinder_system)
    jtj, grad = np.empty((5, 5)), np.empty(5)
    return _cylinder_system(q, axis, u, v, p0, r, jtj, grad), jtj, grad


@njit(cache=True, nogil=True)
def _cylinder_system(q, axis, u, v, p0, r, jtj, grad):
    # as _sphere_system (5 x 5, 5): scalar sums; the radius entry is -1 for every point
    s00 = s01 = s02 = s03 = s04 = s11 = s12 = s13 = s14 = s22 = s23 = s24 = s33 = s34 = 0.0
    g0 = g1 = g2 = g3 = g4 = 0.0
    cost = 0.0
    for i in range(q.shape[0]):
        rx, ry, rz = q[i, 0] - p0[0], q[i, 1] - p0[1], q[i, 2] - p0[2]
        x = rx * u[0] + ry * u[1] + rz * u[2]
        y = rx * v[0] + ry * v[1] + rz * v[2]
        z = rx * axis[0] + ry * axis[1] + rz * axis[2]
        rho = max(np.sqrt(x * x + y * y), 1e-300)
        res = rho - r
        r0, r1 = -x / rho, -y / rho
        r2, r3 = z * r0, z * r1
        cost += res * res
        g0 += r0 * res
        g1 += r1 * res
        g2 += r2 * res
        g3 += r3 * res
        g4 -= res
        s00 += r0 * r0
        s01 += r0 * r1
        s02 += r0 * r2
        s03 += r0 * r3
        s04 -= r0
        s11 += r1 * r1
        s12 += r1 * r2
        s13 += r1 * r3
        s14 -= r1
        s22 += r2 * r2
        s23 += r2 * r3
        s24 -= r2
        s33 += r3 * r3
        s34 -= r3
    _packed_system((s00, s01, s02, s03, s04, s11, s12, s13, s14, s22, s23, s24, s33, s34,
                    float(q.shape[0])), jtj)
    grad[0], grad[1], grad[2], grad[3], grad[4] = g0, g1, g2, g3, g4
    return cost


@njit(cache=True, nogil=True)
def _damped_step(jtj, grad, damping, m, step):
    # the damped system's solution into ``step`` (``m``: work space as ``jtj``); whether
    # it has one (linalg.solve's rule, rel_tol 0)
    for a in range(m.shape[0]):
        for b in range(m.shape[1]):
            m[a, b] = jtj[a, b]
        m[a, a] += damping * (m[a, a] + 1e-12)
        step[a] = -grad[a]
    return solve_in_place(m, step, 0.0)


@njit(cache=True, nogil=True, inline="always")
def _given_up(decrease, cost, n, give_up_rms):
    # Creeping (under 1 % per step) at an rms over twice what will be accepted: the model
    # cannot get there in the iterations left (a mixed region, or the wrong kind).
    return decrease < 0.01 * (cost + decrease) and cost > 4.0 * give_up_rms * give_up_rms * n


@njit(cache=True, nogil=True)
def sphere_lm(q, center, radius, max_iterations, give_up_rms=np.inf):
    """Geometric sphere fit ``|q - c| - r`` from a start; ``(center, radius, converged)``.

    ``converged`` is 1, 0 (not in ``max_iterations``) or -1: given up with the rms still
    above twice ``give_up_rms`` while a step gained under 1 % (see :func:`_given_up`).
    """
    # the model and its system in two buffers each, the trial's swapped in when accepted
    params, trial = np.empty(4), np.empty(4)
    params[:3] = center
    params[3] = radius
    jtj, t_jtj, work = np.empty((4, 4)), np.empty((4, 4)), np.empty((4, 4))
    grad, t_grad, step = np.empty(4), np.empty(4), np.empty(4)
    cost = _sphere_system(q, params, jtj, grad)
    damping = 1e-3
    for _ in range(max_iterations):
        if not _damped_step(jtj, grad, damping, work, step):
            return params[:3], params[3], 0
        if _largest_magnitude(step) <= 1e-10:
            return params[:3], params[3], 1
        for k in range(4):
            trial[k] = params[k] + step[k]
        t_cost = _sphere_system(q, trial, t_jtj, t_grad)
        if not np.isfinite(t_cost):
            damping *= 10.0
            continue
        if t_cost <= cost:
            decrease = cost - t_cost
            params, trial, cost, jtj, t_jtj, grad, t_grad = trial, params, t_cost, t_jtj, jtj, t_grad, grad
            damping = max(damping * 0.1, 1e-9)
            if decrease <= 1e-12 * cost + 1e-30:
                return params[:3], params[3], 1
            if params[3] > RADIUS_LIMIT:
                return params[:3], params[3], 0
            if _given_up(decrease, cost, q.shape[0], give_up_rms):
                return params[:3], params[3], -1
        elif t_cost - cost <= 1e-12 * cost + 1e-30:
            return params[:3], params[3], 1
        else:
            damping *= 10.0
    return params[:3], params[3], 0


@njit(cache=True, nogil=True, inline="always")
def _largest_magnitude(values):
    # np.abs(values).max() without the array of magnitudes (NaN as max propagates it)
    largest = abs(values[0])
    for k in range(1, values.shape[0]):
        value = abs(values[k])
        if value > largest or np.isnan(value):
            largest = value
    return largest


@njit(cache=True, nogil=True)
def cylinder_lm(q, axis, point, radius, max_iterations, give_up_rms=np.inf):
    """Geometric cylinder fit ``|(q - p0) x a| - r`` from a start; ``(axis, point, radius, converged)``.

    ``converged`` as for :func:`sphere_lm`.

    Each step is linearised in a frame whose z axis is the current axis (2 tilt angles,
    2 axis-point shifts, the radius); the axis point is kept nearest the origin of ``q``.
    """
    a = axis / np.sqrt(axis @ axis)
    p0 = point - (point @ a) * a
    r = radius
    u, v = _frame(a)
    # the model, its frame and its system in two buffers each, the trial's swapped in
    # when accepted (as sphere_lm)
    new_a, new_p, new_u, new_v = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    jtj, t_jtj, work = np.empty((5, 5)), np.empty((5, 5)), np.empty((5, 5))
    grad, t_grad, step = np.empty(5), np.empty(5), np.empty(5)
    cost = _cylinder_system(q, a, u, v, p0, r, jtj, grad)
    damping = 1e-3
    for _ in range(max_iterations):
        if not _damped_step(jtj, grad, damping, work, step):
            return a, p0, r, 0
        if _largest_magnitude(step) <= 1e-10:
            return a, p0, r, 1
        for k in range(3):
            new_a[k] = u[k] * step[2] + v[k] * step[3] + a[k]
        new_a /= np.sqrt(new_a @ new_a)
        for k in range(3):
            new_p[k] = p0[k] + u[k] * step[0] + v[k] * step[1]
        along = new_p @ new_a
        for k in range(3):
            new_p[k] = new_p[k] - along * new_a[k]
        new_r = r + step[4]
        _frame_into(new_a, new_u, new_v)
        t_cost = _cylinder_system(q, new_a, new_u, new_v, new_p, new_r, t_jtj, t_grad)
        if not np.isfinite(t_cost):
            damping *= 10.0
            continue
        if t_cost <= cost:
            decrease = cost - t_cost
            a, new_a, u, new_u, v, new_v, p0, new_p = new_a, a, new_u, u, new_v, v, new_p, p0
            r, cost, jtj, t_jtj, grad, t_grad = new_r, t_cost, t_jtj, jtj, t_grad, grad
            damping = max(damping * 0.1, 1e-9)
            if decrease <= 1e-12 * cost + 1e-30:
                return a, p0, r, 1
            if r > RADIUS_LIMIT:
                return a, p0, r, 0
            if _given_up(decrease, cost, q.shape[0], give_up_rms):
                return a, p0, r, -1
        elif t_cost - cost <= 1e-12 * cost + 1e-30:
            return a, p0, r, 1
        else:
            damping *= 10.0
    return a, p0, r, 0


@njit(cache=True, nogil=True)
def _union_reach(cost_a, jtj_a, grad_a, cost_b, jtj_b, grad_b, budget, trusted):
    # First-order lower bound of the distances (their root sum of squares) of part b over
    # the models whose sum of squares over part a stays within ``budget``, both parts
    # linearised at the same model (cost, J^T J and J^T r of each). Part a's models:
    # (d - d0)^T H_a (d - d0) <= spread about its best step d0; part b's distances move by
    # at most sqrt(lambda_max(H_a^-1 H_b) spread) <= sqrt(trace(H_a^-1 H_b) spread).
    # -inf (no answer) when H_a is singular, no model keeps part a within the budget, or
    # some parameter may move beyond ``trusted[k]`` (where the linearisation is trusted).
    k_params = grad_a.shape[0]
    shift, ok = solve(jtj_a, -grad_a, 1e-12)
    if not ok:
        return -np.inf
    spread = budget - cost_a - grad_a @ shift
    if not spread > 0.0:
        return -np.inf
    trace = 0.0
    unit = np.zeros(k_params)
    for k in range(k_params):
        unit[:] = 0.0
        unit[k] = 1.0
        inverse, ok = solve(jtj_a, unit, 1e-12)  # column k of H_a^-1
        if not ok or abs(shift[k]) + np.sqrt(max(inverse[k], 0.0) * spread) > trusted[k]:
            return -np.inf
        for j in range(k_params):  # (H_a^-1 H_b)_kk, H_a^-1 symmetric
            trace += inverse[j] * jtj_b[j, k]
    at_shift = max(cost_b + 2.0 * (grad_b @ shift) + shift @ (jtj_b @ shift), 0.0)
    return np.sqrt(at_shift) - np.sqrt(max(trace, 0.0) * spread)


@njit(cache=True, nogil=True)
def cylinder_union_reach(points, first, axis, point, radius, budget, trusted_share):
    """:func:`_union_reach` for a cylinder (world ``axis``, ``point``, ``radius``): the
    points ``points[first:]`` against the cylinders that keep ``points[:first]`` within
    ``budget`` (a sum of squared distances), linearised at the given one and trusted for
    moves of the axis and radius up to ``trusted_share`` of the radius, tilts up to
    ``trusted_share`` radians."""
    a = axis / np.sqrt(axis @ axis)
    p0 = point - (point @ a) * a
    u, v = _frame(a)
    cost_a, jtj_a, grad_a = _cylinder_normal_equations(points[:first], a, u, v, p0, radius)
    cost_b, jtj_b, grad_b = _cylinder_normal_equations(points[first:], a, u, v, p0, radius)
    # steps: axis point along u, v; axis tilt towards u, v; radius
    move = trusted_share * radius
    trusted = np.array([move, move, trusted_share, trusted_share, move])
    return _union_reach(cost_a, jtj_a, grad_a, cost_b, jtj_b, grad_b, budget, trusted)


@njit(cache=True, nogil=True)
def sphere_union_reach(points, first, center, radius, budget, trusted_share):
    """:func:`cylinder_union_reach` for a sphere (world ``center``, ``radius``; its centre
    and radius trusted to move up to ``trusted_share`` of the radius)."""
    params = np.empty(4)
    params[:3] = center
    params[3] = radius
    cost_a, jtj_a, grad_a = _sphere_normal_equations(points[:first], params)
    cost_b, jtj_b, grad_b = _sphere_normal_equations(points[first:], params)
    return _union_reach(cost_a, jtj_a, grad_a, cost_b, jtj_b, grad_b, budget,
                        np.full(4, trusted_share * radius))


@njit(cache=True, nogil=True)
def circle_scores(n, second, third, fourth, directions, u, v, s):
    """Kasa circle fit of the projection along each direction, from moments up to 4th order.

    The loop form of ``cylinder._Moments.circle_scores`` (see there); returns
    ``(score, cx, cy, radius_sq)`` per direction.
    """
    m = directions.shape[0]
    score = np.empty(m)
    cxs = np.empty(m)
    cys = np.empty(m)
    rsq = np.empty(m)
    for i in range(m):
        # explicit loops: BLAS calls on 3- and 6-vectors cost more than the arithmetic
        a00 = a01 = a11 = b0 = b1 = sum4 = 0.0
        for j in range(3):
            suj = svj = t3j = 0.0
            for k in range(3):
                suj += second[j, k] * u[i, k]
                svj += second[j, k] * v[i, k]
            for k in range(6):
                t3j += third[j, k] * s[i, k]
            a00 += suj * u[i, j]
            a01 += suj * v[i, j]
            a11 += svj * v[i, j]
            b0 += t3j * u[i, j]
            b1 += t3j * v[i, j]
        for j in range(6):
            f = 0.0
            for k in range(6):
                f += fourth[j, k] * s[i, k]
            sum4 += s[i, j] * f
        det = a00 * a11 - a01 * a01
        if abs(det) <= 1e-300:
            det = 1e-300
        cx = 0.5 * (a11 * b0 - a01 * b1) / det
        cy = 0.5 * (a00 * b1 - a01 * b0) / det
        mu = (a00 + a11) / n
        algebraic = (sum4 - n * mu * mu - 2.0 * (b0 * cx + b1 * cy)) / n
        radius_sq = mu + cx * cx + cy * cy
        score[i] = max(algebraic, 0.0) / (4.0 * radius_sq)
        cxs[i], cys[i], rsq[i] = cx, cy, radius_sq
    return score, cxs, cys, rsq


@njit(cache=True, nogil=True)
def _moments(q):
    # second (3x3), third (3x6) and fourth (6x6) moments of centred points, monomials
    # x2 y2 z2 xy xz yz (as cylinder._Moments). The sums in scalars (see
    # _sphere_normal_equations), each the same products added in the same order as
    # array entries updated point by point: the same values
    s00 = s01 = s02 = s11 = s12 = s22 = 0.0
    t00 = t01 = t02 = t03 = t04 = t05 = 0.0
    t10 = t11 = t12 = t13 = t14 = t15 = 0.0
    t20 = t21 = t22 = t23 = t24 = t25 = 0.0
    f00 = f01 = f02 = f03 = f04 = f05 = f11 = f12 = f13 = f14 = f15 = 0.0
    f22 = f23 = f24 = f25 = f33 = f34 = f35 = f44 = f45 = f55 = 0.0
    for i in range(q.shape[0]):
        x, y, z = q[i, 0], q[i, 1], q[i, 2]
        xx, yy, zz, xy, xz, yz = x * x, y * y, z * z, x * y, x * z, y * z
        s00 += x * x
        s01 += x * y
        s02 += x * z
        s11 += y * y
        s12 += y * z
        s22 += z * z
        t00 += x * xx
        t01 += x * yy
        t02 += x * zz
        t03 += x * xy
        t04 += x * xz
        t05 += x * yz
        t10 += y * xx
        t11 += y * yy
        t12 += y * zz
        t13 += y * xy
        t14 += y * xz
        t15 += y * yz
        t20 += z * xx
        t21 += z * yy
        t22 += z * zz
        t23 += z * xy
        t24 += z * xz
        t25 += z * yz
        f00 += xx * xx
        f01 += xx * yy
        f02 += xx * zz
        f03 += xx * xy
        f04 += xx * xz
        f05 += xx * yz
        f11 += yy * yy
        f12 += yy * zz
        f13 += yy * xy
        f14 += yy * xz
        f15 += yy * yz
        f22 += zz * zz
        f23 += zz * xy
        f24 += zz * xz
        f25 += zz * yz
        f33 += xy * xy
        f34 += xy * xz
        f35 += xy * yz
        f44 += xz * xz
        f45 += xz * yz
        f55 += yz * yz
    second = np.empty((3, 3))
    second[0, 0], second[0, 1], second[0, 2] = s00, s01, s02
    second[1, 0], second[1, 1], second[1, 2] = s01, s11, s12  # a product commutes exactly
    second[2, 0], second[2, 1], second[2, 2] = s02, s12, s22
    third = np.empty((3, 6))
    third[0, 0], third[0, 1], third[0, 2], third[0, 3], third[0, 4], third[0, 5] = t00, t01, t02, t03, t04, t05
    third[1, 0], third[1, 1], third[1, 2], third[1, 3], third[1, 4], third[1, 5] = t10, t11, t12, t13, t14, t15
    third[2, 0], third[2, 1], third[2, 2], third[2, 3], third[2, 4], third[2, 5] = t20, t21, t22, t23, t24, t25
    fourth = np.empty((6, 6))
    fourth[0, 0], fourth[0, 1], fourth[0, 2], fourth[0, 3], fourth[0, 4], fourth[0, 5] = f00, f01, f02, f03, f04, f05
    fourth[1, 1], fourth[1, 2], fourth[1, 3], fourth[1, 4], fourth[1, 5] = f11, f12, f13, f14, f15
    fourth[2, 2], fourth[2, 3], fourth[2, 4], fourth[2, 5] = f22, f23, f24, f25
    fourth[3, 3], fourth[3, 4], fourth[3, 5] = f33, f34, f35
    fourth[4, 4], fourth[4, 5] = f44, f45
    fourth[5, 5] = f55
    _symmetrise(fourth)
    return second, third, fourth


@njit(cache=True, nogil=True)
def _projector_rows(directions):
    # coefficients of |P x|^2 (P = I - w w^T) on x2 y2 z2 xy xz yz, per direction
    m = directions.shape[0]
    s = np.empty((m, 6))
    for i in range(m):
        wx, wy, wz = directions[i, 0], directions[i, 1], directions[i, 2]
        s[i, 0], s[i, 1], s[i, 2] = 1 - wx * wx, 1 - wy * wy, 1 - wz * wz
        s[i, 3], s[i, 4], s[i, 5] = -2 * wx * wy, -2 * wx * wz, -2 * wy * wz
    return s


@njit(cache=True, nogil=True)
def _rotate_onto(template, axis, u, v):
    # template vectors given in the frame (u, v, axis) -> world coordinates
    out = np.empty_like(template)
    for i in range(template.shape[0]):
        for k in range(3):
            out[i, k] = template[i, 0] * u[k] + template[i, 1] * v[k] + template[i, 2] * axis[k]
    return out


@njit(cache=True, nogil=True)
def cylinder_start(q, axis_hint, hemisphere, hemi_u, hemi_v, hemi_s, cones):
    """Axis (from ``axis_hint`` unless it is NaN, else a coarse-to-fine search), axis point and radius.

    The search looks for the direction along which the points project best onto a circle
    (Eberly's cylinder fit from moments up to 4th order, the Kasa error divided by
    ``4 r^2`` so that it approximates the mean squared geometric distance and directions
    squashing the points into a small blob are not favoured): it scores the hemisphere
    directions (about 8 deg apart), then each cone template of ``cones`` (a tuple of
    ``(dirs, u, v)`` around +z, 8 and 2 deg) rotated onto the best so far, ending about
    0.5 deg from the optimum. The circle of the projection along the final axis gives the
    point and radius. Returns ``(axis, point, radius)``.
    """
    second, third, fourth = _moments(q)
    n = float(q.shape[0])
    if np.isfinite(axis_hint[0]):
        axis = axis_hint / np.sqrt(axis_hint @ axis_hint)
    else:
        score = circle_scores(n, second, third, fourth, hemisphere, hemi_u, hemi_v, hemi_s)[0]
        axis = hemisphere[np.argmin(score)].copy()
        for dirs_t, u_t, v_t in cones:
            fu, fv = _frame(axis)
            dirs = _rotate_onto(dirs_t, axis, fu, fv)
            score = circle_scores(n, second, third, fourth, dirs, _rotate_onto(u_t, axis, fu, fv),
                                  _rotate_onto(v_t, axis, fu, fv), _projector_rows(dirs))[0]
            axis = dirs[np.argmin(score)].copy()
    u, v = _frame(axis)
    one = np.empty((1, 3))
    one[0] = axis
    uu = np.empty((1, 3))
    uu[0] = u
    vv = np.empty((1, 3))
    vv[0] = v
    _, cx, cy, radius_sq = circle_scores(n, second, third, fourth, one, uu, vv, _projector_rows(one))
    point = cx[0] * u + cy[0] * v
    return axis, point, np.sqrt(max(radius_sq[0], 1e-300))


@njit(cache=True, nogil=True)
def arc_around_axis(points, axis, point):
    """2*pi minus the largest angular gap between consecutive points around the axis."""
    n = points.shape[0]
    if n < 2:
        return 0.0
    a = axis / np.sqrt(axis @ axis)
    u, v = _frame(a)
    angles = np.empty(n)
    for i in range(n):
        rx, ry, rz = points[i, 0] - point[0], points[i, 1] - point[1], points[i, 2] - point[2]
        angles[i] = np.arctan2(rx * v[0] + ry * v[1] + rz * v[2], rx * u[0] + ry * u[1] + rz * u[2])
    angles.sort()
    gap = angles[0] + 2 * np.pi - angles[n - 1]
    for i in range(1, n):
        gap = max(gap, angles[i] - angles[i - 1])
    return 2 * np.pi - gap


@njit(cache=True, nogil=True)
def cap_angle(points, center):
    """Twice the largest angle between a point's direction from ``center`` and the mean direction."""
    n = points.shape[0]
    unit = np.empty((n, 3))
    mx = my = mz = 0.0
    for i in range(n):
        rx, ry, rz = points[i, 0] - center[0], points[i, 1] - center[1], points[i, 2] - center[2]
        length = np.sqrt(rx * rx + ry * ry + rz * rz)
        unit[i, 0], unit[i, 1], unit[i, 2] = rx / length, ry / length, rz / length
        mx += unit[i, 0]
        my += unit[i, 1]
        mz += unit[i, 2]
    norm = np.sqrt(mx * mx + my * my + mz * mz) / n
    if norm < 1e-9:
        return 2 * np.pi
    scale = 1.0 / (norm * n)
    mx, my, mz = mx * scale, my * scale, mz * scale
    lowest = 1.0
    for i in range(n):
        lowest = min(lowest, max(unit[i, 0] * mx + unit[i, 1] * my + unit[i, 2] * mz, -1.0))
    return 2.0 * np.arccos(lowest)


# inline: compiled into its one caller, not as a kernel of its own (numba generates the machine
# code of every kernel with all it calls: a level less is that code generated once less)
@njit(cache=True, nogil=True, inline="always")
def sphere_core(q, max_iterations, inlier_distance, give_up_rms=np.inf):
    """Algebraic start, geometric refinement and the statistics of a sphere on centred, scaled ``q``.

    The start is the paper's Sec. 4.2 with its errata: ``|q|^2 = 2 q.c - t`` with
    ``t = |c|^2 - r^2``, solved by least squares (not the normal equations).
    Returns ``(ok, center, radius, converged, rms, cap, inliers)``; ``ok`` is False when
    that system is rank deficient or gives ``r^2 <= 0``.
    """
    n = q.shape[0]
    design = np.empty((n, 4))
    rhs = np.empty(n)
    for i in range(n):
        design[i, 0], design[i, 1], design[i, 2], design[i, 3] = 2 * q[i, 0], 2 * q[i, 1], 2 * q[i, 2], -1.0
        rhs[i] = q[i, 0] * q[i, 0] + q[i, 1] * q[i, 1] + q[i, 2] * q[i, 2]
    solution, _, rank, _ = np.linalg.lstsq(design, rhs)
    center = solution[:3].copy()
    radius_sq = center @ center - solution[3]
    if rank < 4 or not np.isfinite(radius_sq) or radius_sq <= 0:
        return False, center, 0.0, 0, np.inf, 0.0, 0
    return sphere_refine(q, center, np.sqrt(radius_sq), max_iterations, inlier_distance, give_up_rms)


@njit(cache=True, nogil=True)
def sphere_refine(q, center, radius, max_iterations, inlier_distance, give_up_rms=np.inf):
    """Geometric refinement from a start and the statistics: ``(True, center, radius, converged, rms, cap, inliers)``."""
    center, radius, converged = sphere_lm(q, center, radius, max_iterations, give_up_rms)
    n = q.shape[0]
    squares = 0.0
    inliers = 0
    for i in range(n):
        dx, dy, dz = q[i, 0] - center[0], q[i, 1] - center[1], q[i, 2] - center[2]
        dist = np.sqrt(dx * dx + dy * dy + dz * dz) - radius
        squares += dist * dist
        if abs(dist) <= inlier_distance:
            inliers += 1
    # the cap is judged only for a converged model (_decide._outcome_code): its O(n) pass is
    # spared for the refused ones (NaN in their row)
    cap = cap_angle(q, center) if converged == 1 else np.nan
    return True, center, radius, converged, np.sqrt(squares / n), cap, inliers


# inline: as sphere_core
@njit(cache=True, nogil=True, inline="always")
def cylinder_core(q, axis_hint, hemisphere, hemi_u, hemi_v, hemi_s, cones, max_iterations,
                  inlier_distance, give_up_rms=np.inf):
    """Start (:func:`cylinder_start`), refinement (:func:`cylinder_lm`) and statistics on centred, scaled ``q``.

    Returns ``(axis, point, radius, converged, rms, arc, inliers)``.
    """
    axis, point, radius = cylinder_start(q, axis_hint, hemisphere, hemi_u, hemi_v, hemi_s, cones)
    return cylinder_refine(q, axis, point, radius, max_iterations, inlier_distance, give_up_rms)


@njit(cache=True, nogil=True)
def cylinder_refine(q, axis, point, radius, max_iterations, inlier_distance, give_up_rms=np.inf):
    """Geometric refinement from a start and the statistics: ``(axis, point, radius, converged, rms, arc, inliers)``."""
    axis, point, radius, converged = cylinder_lm(q, axis, point, radius, max_iterations, give_up_rms)
    u, v = _frame(axis)
    n = q.shape[0]
    squares = 0.0
    inliers = 0
    for i in range(n):
        rx, ry, rz = q[i, 0] - point[0], q[i, 1] - point[1], q[i, 2] - point[2]
        x = rx * u[0] + ry * u[1] + rz * u[2]
        y = rx * v[0] + ry * v[1] + rz * v[2]
        dist = np.sqrt(x * x + y * y) - radius
        squares += dist * dist
        if abs(dist) <= inlier_distance:
            inliers += 1
    # the arc is judged only for a converged model (_decide._outcome_code): its sort of the
    # angles is spared for the refused ones (NaN in their row; most failed unions of a merge)
    arc = arc_around_axis(q, axis, point) if converged == 1 else np.nan
    return axis, point, radius, converged, np.sqrt(squares / n), arc, inliers


@njit(cache=True, nogil=True)
def prepare_points(points):
    """Centre, scale and decompose (N, 3) points in one pass: the start of every fit.

    Returns ``(n_bad, centroid, scale, q, eigvals, eigvecs)``: the number of rows with a
    NaN or infinite coordinate (when it is not 0 the rest is not computed), the centroid,
    the rms spread ``scale`` (1 for coincident points), ``q = (points - centroid) / scale``
    and the ascending eigenvalues and eigenvectors (columns) of ``q^T q``.
    """
    n = points.shape[0]
    n_bad = 0
    centroid = np.zeros(3)
    for i in range(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if np.isfinite(x) and np.isfinite(y) and np.isfinite(z):
            centroid[0] += x
            centroid[1] += y
            centroid[2] += z
        else:
            n_bad += 1
    q = np.empty((n, 3))
    if n_bad or n == 0:
        return n_bad, centroid, 1.0, q, np.zeros(3), np.eye(3)
    centroid /= n
    squares = 0.0
    for i in range(n):
        for k in range(3):
            value = points[i, k] - centroid[k]
            q[i, k] = value
            squares += value * value
    scale = np.sqrt(squares / n)
    if scale == 0.0:
        scale = 1.0
    q /= scale
    eigvals, eigvecs = np.linalg.eigh(q.T @ q)
    return n_bad, centroid, scale, q, eigvals, eigvecs


@njit(cache=True, nogil=True)
def plane_of(q, points, centroid, scale, eigvals, eigvecs, inlier_distance):
    """The least-squares plane of prepared points (see :func:`prepare_points`).

    Returns ``(ok, normal, d, rms, inliers)``: the normal is the smallest eigenvector in
    Hesse form (:func:`hesse_form`), rms and inliers as :func:`plane_statistics`; ``ok`` is
    False for coincident or collinear points.
    """
    if collinear(eigvals):
        return False, np.full(3, np.nan), np.nan, np.nan, 0
    normal = eigvecs[:, 0].copy()
    normal /= np.sqrt(normal @ normal)
    normal, d = hesse_form(normal, normal @ centroid, np.abs(centroid).max() + scale)
    rms, inliers = plane_statistics(q, normal, scale, points, d, inlier_distance)
    return True, normal, d, rms, inliers


@njit(cache=True, nogil=True)
def plane_statistics(q, normal, scale, points, d, inlier_distance):
    """rms distance of the centred, scaled ``q`` from the plane through 0 with ``normal`` (in
    the units of ``points``), and the number of ``points`` within ``inlier_distance`` of
    ``normal . p = d``."""
    squares = 0.0
    inliers = 0
    for i in range(q.shape[0]):
        height = q[i, 0] * normal[0] + q[i, 1] * normal[1] + q[i, 2] * normal[2]
        squares += height * height
        distance = points[i, 0] * normal[0] + points[i, 1] * normal[1] + points[i, 2] * normal[2] - d
        if abs(distance) <= inlier_distance:
            inliers += 1
    return scale * np.sqrt(squares / max(q.shape[0], 1)), inliers
