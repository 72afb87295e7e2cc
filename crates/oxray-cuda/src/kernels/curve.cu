// ---------------------------------------------------------------------------------------------
// Built-in curves (guide §5.2, §9.3, §9.6, §9.7): oxray_bvh::curve::CurveSegment::intersect and
// oxray_bvh::poly, operation for operation in double precision. The module is compiled without
// FMA contraction, and IEEE double arithmetic (+, -, *, /, sqrt) rounds as the CPU's does, so
// both devices find the same roots, the same hit and the same u, v.
//
// A leaf slot is the CPU's `CurveSegment` record, 6 float4 (96 bytes): four control points
// (x, y, z, radius), the two ribbon normals (3 floats each), the OptixPrimitiveType code and the
// flags below. Inactive slots have NaN control points, which no ray hits.
// ---------------------------------------------------------------------------------------------

#define CURVE_CAP_START 1u
#define CURVE_CAP_END 2u
#define CURVE_HAS_NORMALS 4u
#define CURVE_COEFFS 11

struct __align__(16) CurveRecord {
    float p[4][4];
    float normals[2][3];
    u32 type;
    u32 flags;
};

struct CurveHit {
    float t, u, v;
    bool back_face;
};

// ----- Polynomials (oxray_bvh::poly::Poly) -----

struct CPoly {
    double c[CURVE_COEFFS];
    int n;
};

__device__ __forceinline__ CPoly cpoly_zero() {
    CPoly p;
    for (int k = 0; k < CURVE_COEFFS; ++k) p.c[k] = 0.0;
    p.n = 0;
    return p;
}

__device__ __forceinline__ CPoly cpoly4(const double* c) {
    CPoly p = cpoly_zero();
    for (int k = 0; k < 4; ++k) p.c[k] = c[k];
    p.n = 4;
    return p;
}

__device__ __forceinline__ double cpoly_eval(const CPoly& p, double u) {
    double acc = 0.0;
    for (int k = p.n - 1; k >= 0; --k) acc = acc * u + p.c[k];
    return acc;
}

__device__ __forceinline__ CPoly cpoly_derivative(const CPoly& p) {
    CPoly d = cpoly_zero();
    for (int k = 1; k < p.n; ++k) d.c[k - 1] = p.c[k] * (double)k;
    d.n = p.n > 0 ? p.n - 1 : 0;
    return d;
}

__device__ __forceinline__ CPoly cpoly_mul(const CPoly& a, const CPoly& b) {
    CPoly p = cpoly_zero();
    if (a.n == 0 || b.n == 0) return p;
    p.n = a.n + b.n - 1;
    if (p.n > CURVE_COEFFS) p.n = CURVE_COEFFS;  // never: the callers' degrees sum below 11
    for (int i = 0; i < a.n; ++i) {
        for (int j = 0; j < b.n; ++j) {
            if (i + j < CURVE_COEFFS) p.c[i + j] += a.c[i] * b.c[j];
        }
    }
    return p;
}

// a + s b
__device__ __forceinline__ CPoly cpoly_add_scaled(const CPoly& a, const CPoly& b, double s) {
    CPoly p = a;
    p.n = a.n > b.n ? a.n : b.n;
    for (int k = 0; k < b.n; ++k) p.c[k] += s * b.c[k];
    return p;
}

__device__ __forceinline__ int cpoly_degree(const CPoly& p) {
    for (int k = p.n - 1; k >= 0; --k) {
        if (p.c[k] != 0.0) return k;
    }
    return -1;
}

__device__ __forceinline__ void cpoly_push(double* out, int& count, double r) {
    if (count < CURVE_COEFFS && (count == 0 || out[count - 1] != r)) out[count++] = r;
}

// Poly::bracketed: the root in [a, b], where p is monotonic and changes sign.
__device__ double cpoly_bracketed(const CPoly& p, const CPoly& d, double a, double b, double fa) {
    const bool neg_at_a = fa < 0.0;
    double u = 0.5 * (a + b);
    for (int i = 0; i < 100; ++i) {
        const double f = cpoly_eval(p, u);
        if (f == 0.0) return u;
        if ((f < 0.0) == neg_at_a) {
            a = u;
        } else {
            b = u;
        }
        const double df = cpoly_eval(d, u);
        const double newton = u - f / df;
        const double next = (newton > a && newton < b) ? newton : 0.5 * (a + b);
        if (fabs(next - u) <= 1e-15 * (1.0 + fabs(u)) || b - a <= 1e-15 * (1.0 + fabs(a))) {
            return next;
        }
        u = next;
    }
    return u;
}

// One level of Poly::roots: the roots of `p` in [lo, hi] from the `nc` roots `crit` of its
// derivative `d`.
__device__ int cpoly_roots_from(const CPoly& p, const CPoly& d, double lo, double hi,
                                const double* crit, int nc, double* out) {
    int count = 0;
    double a = lo;
    double fa = cpoly_eval(p, a);
    double scale = 0.0;
    for (int k = 0; k < p.n; ++k) scale = fmax(scale, fabs(p.c[k]));
    const double tiny = scale * 1e-13;
    for (int k = 0; k <= nc; ++k) {
        const double b = k < nc ? crit[k] : hi;
        const double fb = cpoly_eval(p, b);
        if (fa == 0.0) {
            cpoly_push(out, count, a);
        } else if ((fa < 0.0) != (fb < 0.0) && fb != 0.0) {
            cpoly_push(out, count, cpoly_bracketed(p, d, a, b, fa));
        } else if (k < nc && fabs(fb) <= tiny) {
            cpoly_push(out, count, b);
        }
        a = b;
        fa = fb;
    }
    if (fa == 0.0) cpoly_push(out, count, a);
    return count;
}

// Poly::roots, without recursion: the chain of derivatives, solved from the linear one up,
// each level's roots isolating the next's.
__device__ __noinline__ int cpoly_roots(const CPoly& p, double lo, double hi, double* out) {
    const int deg = cpoly_degree(p);
    if (deg <= 0) return 0;
    CPoly chain[CURVE_COEFFS - 1];
    chain[0] = p;
    for (int k = 1; k < deg; ++k) chain[k] = cpoly_derivative(chain[k - 1]);
    double buf[2][CURVE_COEFFS];
    int cur = 0;
    int n = 0;
    {
        const CPoly& l = chain[deg - 1];
        const double r = -l.c[0] / l.c[1];
        if (r >= lo && r <= hi) buf[cur][n++] = r;
    }
    for (int k = deg - 2; k >= 0; --k) {
        n = cpoly_roots_from(chain[k], chain[k + 1], lo, hi, buf[cur], n, buf[1 - cur]);
        cur = 1 - cur;
    }
    for (int k = 0; k < n; ++k) out[k] = buf[cur][k];
    return n;
}

// ----- Small f64 vectors (glam's DVec3 arithmetic, in its order) -----

struct D3 {
    double x, y, z;
};
__device__ __forceinline__ D3 d3(double x, double y, double z) {
    D3 v;
    v.x = x;
    v.y = y;
    v.z = z;
    return v;
}
__device__ __forceinline__ double d3_dot(D3 a, D3 b) { return (a.x * b.x) + (a.y * b.y) + (a.z * b.z); }
__device__ __forceinline__ D3 d3_sub(D3 a, D3 b) { return d3(a.x - b.x, a.y - b.y, a.z - b.z); }
__device__ __forceinline__ D3 d3_cross(D3 a, D3 b) {
    return d3(a.y * b.z - b.y * a.z, a.z * b.x - b.z * a.x, a.x * b.y - b.x * a.y);
}

// ----- The segment -----

__device__ __forceinline__ bool curve_type_known(u32 t) {
    return (t >= 0x2501u && t <= 0x2505u) || (t >= 0x2507u && t <= 0x250Bu);
}

// CurveType::control_points (round linear for an unknown code).
__device__ __forceinline__ int curve_points(u32 t) {
    switch (t) {
    case 0x2501u:
    case 0x2505u:
    case 0x2508u:
        return 3;
    case 0x2502u:
    case 0x2504u:
    case 0x2507u:
    case 0x2509u:
    case 0x250Au:
    case 0x250Bu:
        return 4;
    default:
        return 2;
    }
}

__device__ __forceinline__ bool curve_active(const CurveRecord& s) {
    if (!curve_type_known(s.type)) return false;
    const int np = curve_points(s.type);
    bool positive = false;
    for (int i = 0; i < np; ++i) {
        for (int k = 0; k < 4; ++k) {
            if (!isfinite(s.p[i][k])) return false;
        }
        if (s.p[i][3] > 0.0f) positive = true;
    }
    for (int i = 0; i < 2; ++i) {
        for (int k = 0; k < 3; ++k) {
            if (!isfinite(s.normals[i][k])) return false;
        }
    }
    return positive;
}

// CurveSegment::power_basis: a[k][d], c(u) = sum a[k] u^k for (x, y, z, r).
__device__ void curve_power_basis(const CurveRecord& s, double a[4][4]) {
    for (int d = 0; d < 4; ++d) {
        const double q0 = (double)s.p[0][d], q1 = (double)s.p[1][d];
        const double q2 = (double)s.p[2][d], q3 = (double)s.p[3][d];
        double c0, c1, c2, c3;
        switch (s.type) {
        case 0x2501u:
        case 0x2505u:
        case 0x2508u:
            c0 = 0.5 * (q0 + q1);
            c1 = q1 - q0;
            c2 = 0.5 * (q0 - 2.0 * q1 + q2);
            c3 = 0.0;
            break;
        case 0x2502u:
        case 0x2509u:
            c0 = (q0 + 4.0 * q1 + q2) / 6.0;
            c1 = (q2 - q0) / 2.0;
            c2 = (q0 - 2.0 * q1 + q2) / 2.0;
            c3 = (-q0 + 3.0 * q1 - 3.0 * q2 + q3) / 6.0;
            break;
        case 0x2504u:
        case 0x250Au:
            c0 = q1;
            c1 = 0.5 * (q2 - q0);
            c2 = 0.5 * (2.0 * q0 - 5.0 * q1 + 4.0 * q2 - q3);
            c3 = 0.5 * (-q0 + 3.0 * q1 - 3.0 * q2 + q3);
            break;
        case 0x2507u:
        case 0x250Bu:
            c0 = q0;
            c1 = 3.0 * (q1 - q0);
            c2 = 3.0 * (q0 - 2.0 * q1 + q2);
            c3 = -q0 + 3.0 * q1 - 3.0 * q2 + q3;
            break;
        default:  // round linear
            c0 = q0;
            c1 = q1 - q0;
            c2 = 0.0;
            c3 = 0.0;
            break;
        }
        a[0][d] = c0;
        a[1][d] = c1;
        a[2][d] = c2;
        a[3][d] = c3;
    }
}

// The Bézier control points of power-basis coefficients `c` (degree 3).
__device__ __forceinline__ void curve_bezier(const double* c, double b[4]) {
    b[0] = c[0];
    b[1] = c[0] + c[1] / 3.0;
    b[2] = c[0] + 2.0 * c[1] / 3.0 + c[2] / 3.0;
    b[3] = c[0] + c[1] + c[2] + c[3];
}

__device__ __forceinline__ void curve_hull(const double* c, double& lo, double& hi) {
    double b[4];
    curve_bezier(c, b);
    lo = __longlong_as_double(0x7ff0000000000000ll);
    hi = -lo;
    for (int k = 0; k < 4; ++k) {
        lo = fmin(lo, b[k]);
        hi = fmax(hi, b[k]);
    }
}

// The distance from the origin to the convex hull of four points of the plane.
__device__ double curve_hull_distance_2d(const double px[4], const double py[4]) {
    auto cross = [](double ax, double ay, double bx, double by) { return ax * by - ay * bx; };
    auto inside = [&](int a, int b, int c) {
        const double s1 = cross(px[a], py[a], px[b], py[b]);
        const double s2 = cross(px[b], py[b], px[c], py[c]);
        const double s3 = cross(px[c], py[c], px[a], py[a]);
        return (s1 >= 0.0 && s2 >= 0.0 && s3 >= 0.0) || (s1 <= 0.0 && s2 <= 0.0 && s3 <= 0.0);
    };
    if (inside(0, 1, 2) || inside(0, 1, 3) || inside(0, 2, 3) || inside(1, 2, 3)) return 0.0;
    double d = __longlong_as_double(0x7ff0000000000000ll);
    for (int i = 0; i < 4; ++i) {
        for (int j = i + 1; j < 4; ++j) {
            const double abx = px[j] - px[i], aby = py[j] - py[i];
            const double len2 = abx * abx + aby * aby;
            double t = 0.0;
            if (len2 > 0.0) {
                t = -(px[i] * abx + py[i] * aby) / len2;
                if (t < 0.0) t = 0.0;
                if (t > 1.0) t = 1.0;
            }
            const double qx = px[i] + abx * t, qy = py[i] + aby * t;
            d = fmin(d, sqrt(qx * qx + qy * qy));
        }
    }
    return d;
}

// The frame whose z axis is the ray (glam's DVec3::any_orthonormal_pair).
struct CurveFrame {
    D3 o, d, e1, e2;
};

__device__ __forceinline__ double curve_signum(double z) {
    return isnan(z) ? z : copysign(1.0, z);
}

// The minimum of a unimodal `f` on [lo, hi] (golden-section search).
template <typename F>
__device__ double curve_golden_min(const F& f, double lo, double hi) {
    const double G = 0.6180339887498948;
    double a = hi - G * (hi - lo);
    double b = lo + G * (hi - lo);
    double fa = f(a), fb = f(b);
    for (int i = 0; i < 80; ++i) {
        if (fa < fb) {
            hi = b;
            b = a;
            fb = fa;
            a = hi - G * (hi - lo);
            fa = f(a);
        } else {
            lo = a;
            a = b;
            fa = fb;
            b = lo + G * (hi - lo);
            fb = f(b);
        }
        if (hi - lo < 1e-15) break;
    }
    return 0.5 * (lo + hi);
}

// CurveSegment::round: the round-curve test in the ray's frame; t in world units.
__device__ __noinline__ bool curve_round(const CurveRecord& s, const double a[4][4],
                                         const CurveFrame& fr, const CPoly& pz, const CPoly& dd,
                                         double zmin, double zmax, double hz0, double hz1,
                                         double rmax, double& t_out, double& u_out) {
    const bool linear = s.type == 0x2503u;
    double roots[CURVE_COEFFS];
    const int nr = cpoly_roots(dd, 0.0, 1.0, roots);
    if (nr == 0 && cpoly_eval(dd, 0.5) < 0.0) return false;
    if (zmin >= hz0 - rmax && zmin <= hz1 + rmax) {
        CPoly unit = cpoly_zero();
        unit.c[0] = 1.0;
        unit.n = 1;
        const CPoly zs = cpoly_add_scaled(pz, unit, -zmin);
        const CPoly e = cpoly_add_scaled(cpoly_mul(zs, zs), dd, -1.0);
        double crit[CURVE_COEFFS];
        const int nc = cpoly_roots(cpoly_derivative(e), 0.0, 1.0, crit);
        bool inside = false;
        for (int k = 0; k < nc; ++k) {
            const double u = crit[k];
            if (u > 0.0 && u < 1.0 && cpoly_eval(e, u) < 0.0) inside = true;
        }
        if (inside || (linear && (cpoly_eval(e, 0.0) < 0.0 || cpoly_eval(e, 1.0) < 0.0))) {
            return false;
        }
    }
    const double inf = __longlong_as_double(0x7ff0000000000000ll);
    auto t0 = [&](double u) {
        const double d = cpoly_eval(dd, u);
        return d >= 0.0 ? cpoly_eval(pz, u) - sqrt(d) : inf;
    };
    bool have = false;
    double bt = 0.0, bu = 0.0;
    auto offer = [&](double t, double u) {
        if (t >= zmin && t <= zmax && (!have || t < bt)) {
            have = true;
            bt = t;
            bu = u;
        }
    };
    double bounds[CURVE_COEFFS + 2];
    bounds[0] = 0.0;
    for (int k = 0; k < nr; ++k) bounds[k + 1] = roots[k];
    bounds[nr + 1] = 1.0;
    const CPoly dz = cpoly_derivative(pz);
    const CPoly dd1 = cpoly_derivative(dd);
    const CPoly p = cpoly_add_scaled(cpoly_mul(cpoly_mul(dz, dz), dd), cpoly_mul(dd1, dd1), -0.25);
    double cp[CURVE_COEFFS];
    const int ncp = cpoly_roots(p, 0.0, 1.0, cp);
    for (int w = 0; w + 1 < nr + 2; ++w) {
        const double lo = bounds[w], hi = bounds[w + 1];
        if (hi <= lo || cpoly_eval(dd, 0.5 * (lo + hi)) < 0.0) continue;
        bool found = false;
        for (int k = 0; k < ncp; ++k) {
            const double u = cp[k];
            if (!(u > lo && u < hi)) continue;
            if (cpoly_eval(dz, u) * cpoly_eval(dd1, u) < 0.0) continue;
            auto slope = [&](double v) {
                return cpoly_eval(dz, v) - cpoly_eval(dd1, v) / (2.0 * sqrt(fmax(cpoly_eval(dd, v), 0.0)));
            };
            const double h = 1e-6 * (hi - lo);
            if (slope(fmax(u - h, lo)) <= 0.0 && slope(fmin(u + h, hi)) >= 0.0) {
                found = true;
                offer(t0(u), u);
            }
        }
        for (int e = 0; e < 2; ++e) {
            const double end = e == 0 ? 0.0 : 1.0;
            if ((lo == end || hi == end) && linear) {
                found = true;
                offer(t0(end), end);
            }
        }
        if (!found && lo > 0.0 && hi < 1.0) {
            const double u = curve_golden_min(t0, lo, hi);
            offer(t0(u), u);
        }
    }
    // Flat caps at the strand's ends (§5.2): discs facing out of the tube.
    for (int e = 0; e < 2; ++e) {
        const u32 flag = e == 0 ? CURVE_CAP_START : CURVE_CAP_END;
        const double u = e == 0 ? 0.0 : 1.0;
        if ((s.flags & flag) == 0u) continue;
        // CurveSegment::eval and ::tangent at u.
        double v[4], tg[3];
        for (int d = 0; d < 4; ++d) v[d] = ((a[3][d] * u + a[2][d]) * u + a[1][d]) * u + a[0][d];
        for (int d = 0; d < 3; ++d) tg[d] = (3.0 * a[3][d] * u + 2.0 * a[2][d]) * u + a[1][d];
        const D3 c = d3(v[0], v[1], v[2]);
        const double rad = v[3];
        const D3 n = d3(tg[0], tg[1], tg[2]);
        const double dn = d3_dot(fr.d, n);
        if ((u == 0.0 && dn <= 0.0) || (u == 1.0 && dn >= 0.0)) continue;
        const double t = d3_dot(d3_sub(c, fr.o), n) / dn;
        const D3 q = d3(fr.o.x + fr.d.x * t, fr.o.y + fr.d.y * t, fr.o.z + fr.d.z * t);
        const D3 pc = d3_sub(q, c);
        if (d3_dot(pc, pc) <= rad * rad) offer(t, u);
    }
    if (!have) return false;
    t_out = bt;
    u_out = bu;
    return true;
}

// CurveSegment::ribbon: the ribbon test in the ray's frame; t in world units.
__device__ __noinline__ bool curve_ribbon(const CurveRecord& s, const double a[4][4],
                                          const CurveFrame& fr, const CPoly& px, const CPoly& py,
                                          const CPoly& pz, const CPoly& pr, const CPoly& dd,
                                          double zmin, double zmax, double& t_out, CurveHit& hit) {
    bool have = false;
    double bt = 0.0;
    double roots[CURVE_COEFFS];
    double t1[3], t2[3];
    {
        const D3 q1 = d3(a[1][0] * 1.0, a[1][1] * 1.0, a[1][2] * 1.0);
        const D3 q2 = d3(a[2][0] * 2.0, a[2][1] * 2.0, a[2][2] * 2.0);
        t1[0] = d3_dot(q1, fr.e1);
        t1[1] = d3_dot(q1, fr.e2);
        t1[2] = d3_dot(q1, fr.d);
        t2[0] = d3_dot(q2, fr.e1);
        t2[1] = d3_dot(q2, fr.e2);
        t2[2] = d3_dot(q2, fr.d);
    }
    auto tan = [&](double u) { return d3(t1[0] + t2[0] * u, t1[1] + t2[1] * u, t1[2] + t2[2] * u); };
    auto consider = [&](double u, D3 w) {
        const double xu = cpoly_eval(px, u), yu = cpoly_eval(py, u);
        const double zu = cpoly_eval(pz, u), ru = cpoly_eval(pr, u);
        const double ww = w.x * w.x + w.y * w.y;
        if (isnan(ww) || ww <= 0.0 || isnan(ru) || ru <= 0.0) return;
        const double sp = -(xu * w.x + yu * w.y) / ww;
        const double t = zu + sp * w.z;
        const double v = sp * sqrt(d3_dot(w, w)) / ru;
        if (!(v >= -1.0 && v <= 1.0) || t < zmin || t > zmax) return;
        if (have && bt <= t) return;
        const D3 tu = tan(u);
        const double nz = tu.x * w.y - w.x * tu.y;
        have = true;
        bt = t;
        hit.u = (float)u;
        hit.v = (float)v;
        hit.back_face = nz > 0.0;
    };
    if ((s.flags & CURVE_HAS_NORMALS) != 0u) {
        const D3 m0 = d3((double)s.normals[0][0], (double)s.normals[0][1], (double)s.normals[0][2]);
        const D3 m1 = d3((double)s.normals[1][0], (double)s.normals[1][1], (double)s.normals[1][2]);
        const D3 n0 = d3(d3_dot(m0, fr.e1), d3_dot(m0, fr.e2), d3_dot(m0, fr.d));
        const D3 n1 = d3(d3_dot(m1, fr.e1), d3_dot(m1, fr.e2), d3_dot(m1, fr.d));
        auto nn = [&](double u) {
            return d3(n0.x + (n1.x - n0.x) * u, n0.y + (n1.y - n0.y) * u, n0.z + (n1.z - n0.z) * u);
        };
        const D3 w0 = d3_cross(nn(0.0), tan(0.0));
        const D3 wh = d3_cross(nn(0.5), tan(0.5));
        const D3 w1 = d3_cross(nn(1.0), tan(1.0));
        CPoly wx = cpoly_zero(), wy = cpoly_zero();
        wx.n = wy.n = 3;
        wx.c[0] = w0.x;
        wx.c[1] = 4.0 * wh.x - 3.0 * w0.x - w1.x;
        wx.c[2] = 2.0 * w0.x + 2.0 * w1.x - 4.0 * wh.x;
        wy.c[0] = w0.y;
        wy.c[1] = 4.0 * wh.y - 3.0 * w0.y - w1.y;
        wy.c[2] = 2.0 * w0.y + 2.0 * w1.y - 4.0 * wh.y;
        const CPoly g = cpoly_add_scaled(cpoly_mul(px, wy), cpoly_mul(py, wx), -1.0);
        const int n = cpoly_roots(g, 0.0, 1.0, roots);
        for (int k = 0; k < n; ++k) consider(roots[k], d3_cross(nn(roots[k]), tan(roots[k])));
    } else {
        const CPoly f =
            cpoly_add_scaled(cpoly_mul(px, cpoly_derivative(px)), cpoly_mul(py, cpoly_derivative(py)), 1.0);
        const int n = cpoly_roots(f, 0.0, 1.0, roots);
        for (int k = 0; k < n; ++k) {
            const double u = roots[k];
            if (cpoly_eval(dd, u) >= 0.0) {
                const D3 tu = tan(u);
                consider(u, d3(tu.y, -tu.x, 0.0));
            }
        }
    }
    if (!have) return false;
    t_out = bt;
    return true;
}

// CurveSegment::intersect: the nearest front-face hit (or ribbon hit) of org + t dir in
// [tmin, tmax].
__device__ __noinline__ bool curve_intersect(const CurveRecord& s, float3 org, float3 dir,
                                             float tmin, float tmax, CurveHit& hit) {
    const D3 dv = d3((double)dir.x, (double)dir.y, (double)dir.z);
    const double len = sqrt(d3_dot(dv, dv));
    if (!(len > 0.0) || !curve_active(s)) return false;
    CurveFrame fr;
    fr.o = d3((double)org.x, (double)org.y, (double)org.z);
    fr.d = d3(dv.x / len, dv.y / len, dv.z / len);
    {
        const double sign = curve_signum(fr.d.z);
        const double aa = -1.0 / (sign + fr.d.z);
        const double b = fr.d.x * fr.d.y * aa;
        fr.e1 = d3(1.0 + sign * fr.d.x * fr.d.x * aa, sign * b, -sign * fr.d.x);
        fr.e2 = d3(b, sign + fr.d.y * fr.d.y * aa, -fr.d.y);
    }
    const double zmin = (double)tmin * len, zmax = (double)tmax * len;
    double a[4][4];
    curve_power_basis(s, a);
    double x[4], y[4], z[4], r[4];
    for (int k = 0; k < 4; ++k) {
        D3 q = d3(a[k][0], a[k][1], a[k][2]);
        if (k == 0) q = d3_sub(q, fr.o);
        x[k] = d3_dot(q, fr.e1);
        y[k] = d3_dot(q, fr.e2);
        z[k] = d3_dot(q, fr.d);
        r[k] = a[k][3];
    }
    double rmax = 0.0;
    {
        double cr[4] = {a[0][3], a[1][3], a[2][3], a[3][3]};
        double br[4];
        curve_bezier(cr, br);
        for (int k = 0; k < 4; ++k) rmax = fmax(rmax, fabs(br[k]));
    }
    double hx0, hx1, hy0, hy1, hz0, hz1;
    curve_hull(x, hx0, hx1);
    curve_hull(y, hy0, hy1);
    curve_hull(z, hz0, hz1);
    if (hx0 - rmax > 0.0 || hx1 + rmax < 0.0 || hy0 - rmax > 0.0 || hy1 + rmax < 0.0 ||
        hz1 + rmax < zmin || hz0 - rmax > zmax) {
        return false;
    }
    {
        double bx[4], by[4];
        curve_bezier(x, bx);
        curve_bezier(y, by);
        if (curve_hull_distance_2d(bx, by) > rmax) return false;
    }
    const CPoly px = cpoly4(x), py = cpoly4(y), pz = cpoly4(z), pr = cpoly4(r);
    const CPoly dd =
        cpoly_add_scaled(cpoly_add_scaled(cpoly_mul(pr, pr), cpoly_mul(px, px), -1.0), cpoly_mul(py, py), -1.0);
    double t;
    CurveHit h;
    h.t = 0.0f;
    h.u = 0.0f;
    h.v = 0.0f;
    h.back_face = false;
    if (s.type == 0x2505u) {
        if (!curve_ribbon(s, a, fr, px, py, pz, pr, dd, zmin, zmax, t, h)) return false;
    } else {
        double u;
        if (!curve_round(s, a, fr, pz, dd, zmin, zmax, hz0, hz1, rmax, t, u)) return false;
        h.u = (float)u;
    }
    const float tf = (float)(t / len);
    if (!(tf >= tmin && tf <= tmax)) return false;
    h.t = tf;
    hit = h;
    return true;
}

__device__ __forceinline__ CurveRecord load_curve(const float4* __restrict__ curves, u32 s) {
    CurveRecord c;
    float4* w = reinterpret_cast<float4*>(&c);
    for (int k = 0; k < 6; ++k) w[k] = load_ro(curves + 6 * (size_t)s + k);
    return c;
}

// The hit kind of a curve hit: 0x80 | (the type's low byte) << 1 | back face.
__device__ __forceinline__ u32 curve_hit_kind(u32 type, bool back_face) {
    return 0x80u | ((type & 0xFFu) << 1) | (back_face ? 1u : 0u);
}

// The curves' kind of built-in primitive for the query kernels (SphereLeaf in trace.cu).
struct CurveLeaf {
    static __device__ __forceinline__ bool hit(const TraceRay& r, const float4* __restrict__ curves,
                                               u32 s, float tmax, Best& best) {
        CurveHit h;
        if (!curve_intersect(load_curve(curves, s), r.org, r.dir, r.tmin, tmax, h)) return false;
        best.t = h.t;
        best.u = h.u;
        best.v = h.v;
        best.slot = s | (h.back_face ? BACK_FACE_BIT : 0u);
        return true;
    }
};

#ifndef OXRAY_NO_QUERY_KERNELS

extern "C" __global__ void __launch_bounds__(128)
    oxray_closest_curves(const float4* __restrict__ nodes, const float4* __restrict__ curves,
                         const float4* __restrict__ rays, uint4* __restrict__ hits, u32 n) {
    builtin_entry<false, CurveLeaf>(nodes, curves, rays, hits, nullptr, n);
}

extern "C" __global__ void __launch_bounds__(128)
    oxray_occluded_curves(const float4* __restrict__ nodes, const float4* __restrict__ curves,
                          const float4* __restrict__ rays, unsigned char* __restrict__ occluded,
                          u32 n) {
    builtin_entry<true, CurveLeaf>(nodes, curves, rays, nullptr, occluded, n);
}

#endif  // OXRAY_NO_QUERY_KERNELS
