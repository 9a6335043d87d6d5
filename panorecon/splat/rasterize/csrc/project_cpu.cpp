// EWA projection of 3D Gaussians into pinhole cameras on the CPU: forward and hand-written backward, parallel
// over Gaussians. The same arithmetic as the PyTorch reference (projection.py), which defines the rules: near <
// z < far; the Jacobian taken at the view direction clamped to the image's extent plus 30 % of the half field
// of view; cov2d = J R rot(q) diag(s)^2 rot(q)^T R^T J^T + eps2d I; radius = ceil(3 sqrt(largest
// eigenvalue)), at most 2^30 px; radius 0 marks a culled Gaussian. Templated on the scalar type (float for
// training, double for tests). The pairs a vectorised bound does not cull run the exact path 32 bytes of Gaussians
// at a time, one per lane (8 floats, 4 doubles), with no multiply-add contracted, so every lane rounds as scalar code
// of the same formulas: at 331k Gaussians and 33k kept pairs, the forward took 2.2-2.9 ms and the backward 2.3-2.7 ms
// one Gaussian at a time, and take 1.6-2.2 and 1.4-1.8 ms (two threads; outputs byte-identical).
// Backward: a culled (camera, Gaussian) pair gets no gradient, since the compositor never reads its outputs.
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include "parallel_cpu.h"
#include <algorithm>
#include <cmath>
#include <type_traits>
#include <vector>

namespace {

template <typename T>
struct Camera {
  T R[9], t[3], fx, fy, cx, cy, lo_x, hi_x, lo_y, hi_y;
  Camera(const T* V, const T* K, int64_t W, int64_t H) {
    for (int r = 0; r < 3; ++r) {
      for (int k = 0; k < 3; ++k) R[r * 3 + k] = V[r * 4 + k];
      t[r] = V[r * 4 + 3];
    }
    fx = K[0]; fy = K[4]; cx = K[2]; cy = K[5];
    const T tan_x = T(0.5) * W / fx, tan_y = T(0.5) * H / fy;
    lo_x = -(cx / fx + T(0.3) * tan_x); hi_x = (W - cx) / fx + T(0.3) * tan_x;
    lo_y = -(cy / fy + T(0.3) * tan_y); hi_y = (H - cy) / fy + T(0.3) * tan_y;
  }
};

// Helpers on GCC vectors of T, whose lanes are Gaussians: std::max's and std::min's choices (NaN included), a
// broadcast, a lane-wise square root.
template <typename V> inline V max_of(V a, V b) { return (a < b) ? b : a; }
template <typename V> inline V min_of(V a, V b) { return (b < a) ? b : a; }
template <typename V, typename S> inline V splat(S x) {  // x as V's element type, in every lane
  return V{} + static_cast<std::remove_cv_t<std::remove_reference_t<decltype(V{}[0])>>>(x);  // 0 + x == x exactly for x != -0
}
template <typename V> inline V sqrt_of(V x) {
  for (size_t i = 0; i < sizeof(V) / sizeof(x[0]); ++i) x[i] = std::sqrt(x[i]);
  return x;
}

// Rotation matrix (row-major) of the normalised wxyz quaternion; a norm <= 1e-12 reads as the identity.
template <typename V>
inline void quat_rotmat(const V* q4, V* Rq, V* qn, V& norm) {
  norm = sqrt_of(q4[0] * q4[0] + q4[1] * q4[1] + q4[2] * q4[2] + q4[3] * q4[3]);
  const auto big = norm > splat<V>(1e-12);
  for (int k = 0; k < 4; ++k) qn[k] = big ? q4[k] / norm : splat<V>(k == 0 ? 1 : 0);
  const V w = qn[0], x = qn[1], y = qn[2], z = qn[3];
  Rq[0] = 1 - 2 * (y * y + z * z); Rq[1] = 2 * (x * y - w * z); Rq[2] = 2 * (x * z + w * y);
  Rq[3] = 2 * (x * y + w * z); Rq[4] = 1 - 2 * (x * x + z * z); Rq[5] = 2 * (y * z - w * x);
  Rq[6] = 2 * (x * z - w * y); Rq[7] = 2 * (y * z + w * x); Rq[8] = 1 - 2 * (x * x + y * y);
}

// The quantities of one (camera, Gaussian) pair that forward and backward share: view() the camera-space mean and
// the Jacobian's entries, cov() the 2D covariance (a b; b c) from them and M = rot(q) diag(s). V: a vector of T whose
// lanes are Gaussians, each computed by the scalar formulas in the same order (no multiply-add contracted, so each
// lane rounds as scalar code would).
template <typename T, typename V>
struct Pair {
  V p[3], zs, rx, ry, j00, j02, j11, j12, T0[3], T1[3], A0[3], A1[3], a, b, c, det;
  decltype(V{} < V{}) z_ok;
  void view(const Camera<T>& cam, const V* m, T near, T far) {
    for (int r = 0; r < 3; ++r)
      p[r] = cam.R[r * 3] * m[0] + cam.R[r * 3 + 1] * m[1] + cam.R[r * 3 + 2] * m[2] + cam.t[r];
    z_ok = (p[2] > near) & (p[2] < far);
    zs = z_ok ? p[2] : splat<V>(T(1));
    rx = min_of(max_of(p[0] / zs, splat<V>(cam.lo_x)), splat<V>(cam.hi_x));
    ry = min_of(max_of(p[1] / zs, splat<V>(cam.lo_y)), splat<V>(cam.hi_y));
    j00 = cam.fx / zs; j02 = -cam.fx * rx / zs; j11 = cam.fy / zs; j12 = -cam.fy * ry / zs;
  }
  void cov(const Camera<T>& cam, const V* M, T eps2d) {
    for (int k = 0; k < 3; ++k) {
      T0[k] = j00 * cam.R[k] + j02 * cam.R[6 + k];
      T1[k] = j11 * cam.R[3 + k] + j12 * cam.R[6 + k];
    }
    for (int k = 0; k < 3; ++k) {
      A0[k] = T0[0] * M[k] + T0[1] * M[3 + k] + T0[2] * M[6 + k];
      A1[k] = T1[0] * M[k] + T1[1] * M[3 + k] + T1[2] * M[6 + k];
    }
    a = A0[0] * A0[0] + A0[1] * A0[1] + A0[2] * A0[2] + eps2d;
    b = A0[0] * A1[0] + A0[1] * A1[1] + A0[2] * A1[2];
    c = A1[0] * A1[0] + A1[1] * A1[1] + A1[2] * A1[2] + eps2d;
    det = a * c - b * b;
  }
  void compute(const Camera<T>& cam, const V* m, const V* M, T near, T far, T eps2d) {
    view(cam, m, near, far);
    cov(cam, M, eps2d);
  }
};

// Sets maybe[k] = 0 for the Gaussians n0 + k (k < len) that camera cam surely culls: z outside (near, far) by a
// margin, or the mean farther off the image, on one axis, than r_max, a bound on the radius the exact path computes:
// lambda_max(A A^T + eps I) <= |A|_F^2 + eps <= |J|_F^2 s_max^2 + eps (A = J R rot(q) diag(s)), and the radius
// reads lambda as mid + sqrt(max(mid^2 - det, 0.01)) <= a + c + 0.1, so r = ceil(3 sqrt(lambda)) <= 3 sqrt(Q) + 1
// with Q = |J|_F^2 s_max^2 + 2 eps + 0.1. The distances here use 1 / z where the exact path divides (a few ulps
// apart), which the margins (1 % on Q, 2 px plus 1e-5 of the coordinates) cover; a NaN or an infinite Q leaves the
// pair to the exact path. Vectors across Gaussians, in AVX-512 and AVX2 + FMA clones where the CPU has them (the loader picks):
// the baseline build ran these 8-lane vectors as pairs of SSE registers, and the projection's forward took 3.6 ms at
// 330k Gaussians where it takes 2.0 ms now (two threads, the target command's model). The exact path stays in the
// baseline build, so its outputs keep their bits; here a multiply-add's rounding moves no bound past its margin.
#if defined(__x86_64__) && defined(__GNUC__)
#define PR_PROJECT_CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default"), noinline))
#else
#define PR_PROJECT_CLONES
#endif
template <typename T>
PR_PROJECT_CLONES void maybe_kept(const Camera<T>& cam, const T* means, const T* scales, int64_t n0, int64_t len,
                                  T near, T far, T eps2d, T W, T H, uint8_t* maybe) {
  T R[9], t[3];  // locals: the byte stores to maybe may alias anything, and would force reloads of cam's fields
  for (int i = 0; i < 9; ++i) R[i] = cam.R[i];
  for (int i = 0; i < 3; ++i) t[i] = cam.t[i];
  const T fx = cam.fx, fy = cam.fy, cx = cam.cx, cy = cam.cy, lo_x = cam.lo_x, hi_x = cam.hi_x, lo_y = cam.lo_y,
          hi_y = cam.hi_y, z_lo = near * T(0.999) - T(1e-6), z_hi = far * T(1.001), q0 = 2 * eps2d + T(0.1);
  typedef T vec __attribute__((vector_size(32)));  // GCC/Clang vector extensions: 8 floats or 4 doubles
  constexpr int L = 32 / sizeof(T);
  const vec zero = {};
  auto vmax = [](vec a, vec b) { return a > b ? a : b; };
  auto vabs = [](vec a) { return a < 0 ? -a : a; };
  for (int64_t k0 = 0; k0 < len; k0 += L) {
    vec mx, my, mz, sx;  // the lanes past len repeat the last Gaussian
    for (int i = 0; i < L; ++i) {
      const int64_t n = n0 + std::min<int64_t>(k0 + i, len - 1);
      mx[i] = means[n * 3]; my[i] = means[n * 3 + 1]; mz[i] = means[n * 3 + 2];
      sx[i] = std::max(std::max(std::abs(scales[n * 3]), std::abs(scales[n * 3 + 1])), std::abs(scales[n * 3 + 2]));
    }
    const vec x = R[0] * mx + R[1] * my + R[2] * mz + t[0];
    const vec y = R[3] * mx + R[4] * my + R[5] * mz + t[1];
    const vec z = R[6] * mx + R[7] * my + R[8] * mz + t[2];
    const auto z_maybe = (z > z_lo) & (z < z_hi);
    const vec inv = (zero + 1) / (z_maybe ? z : zero + 1);
    const vec rx = vmax(x * inv, zero + lo_x), ry = vmax(y * inv, zero + lo_y);
    const vec rxc = rx < hi_x ? rx : zero + hi_x, ryc = ry < hi_y ? ry : zero + hi_y;
    const vec jf = (fx * fx * (1 + rxc * rxc) + fy * fy * (1 + ryc * ryc)) * inv * inv;
    const vec Q = (jf * sx * sx + q0) * T(1.01);
    const vec u = fx * x * inv + cx, v = fy * y * inv + cy;
    const vec du = vmax(vmax(-u, u - W), zero), dv = vmax(vmax(-v, v - H), zero);
    const vec d = vmax(du, dv) - 2 - T(1e-5) * (vabs(u) + vabs(v));  // a NaN in u or v stays NaN here
    const auto keep = z_maybe & ~((d >= 0) & (d * d >= 9 * Q));
    for (int i = 0; i < L && k0 + i < len; ++i) maybe[k0 + i] = keep[i] != 0;
  }
}

#if defined(__x86_64__) && defined(__GNUC__)
// AVX-512, AVX2 and baseline builds, none of which contracts a multiply and an add into one rounding
#define PR_LANES_CLONES \
  __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default"), optimize("fp-contract=off")))
#else
#define PR_LANES_CLONES
#endif

// 32 bytes of T, as a type that keeps its vector attribute when passed as a template argument (a dependent typedef
// would lose it)
template <typename T> struct Lanes;
template <> struct Lanes<float> { typedef float type __attribute__((vector_size(32))); };
template <> struct Lanes<double> { typedef double type __attribute__((vector_size(32))); };

// The Gaussians idx[0 .. nl) in the lanes of V (the lanes past nl repeat the last one): mean m, scale s, and from
// them rot(q) (Rq), the normalised quaternion qn, its norm and M = rot(q) diag(s), which both passes need.
template <typename T, typename V>
struct GaussianLanes {
  V m[3], s[3], q4[4], Rq[9], qn[4], norm, M[9];
  GaussianLanes(const int64_t* idx, int nl, const T* means, const T* quats, const T* scales) {
    for (int i = 0; i < (int)(sizeof(V) / sizeof(T)); ++i) {
      const int64_t n = idx[std::min(i, nl - 1)];
      for (int k = 0; k < 3; ++k) { m[k][i] = means[n * 3 + k]; s[k][i] = scales[n * 3 + k]; }
      for (int k = 0; k < 4; ++k) q4[k][i] = quats[n * 4 + k];
    }
    quat_rotmat(q4, Rq, qn, norm);
    for (int i = 0; i < 9; ++i) M[i] = Rq[i] * s[i % 3];
  }
};

// Calls fn(idx, nl) for the n in [b, e) with keep(n), L of them at a time (the last call may hold fewer).
template <int L, typename Keep, typename Fn>
inline void in_lanes(int64_t b, int64_t e, Keep keep, Fn fn) {
  int64_t idx[L];
  int nl = 0;
  for (int64_t n = b; n < e; ++n) {
    if (!keep(n)) continue;
    idx[nl++] = n;
    if (nl == L) { fn(idx, nl); nl = 0; }
  }
  if (nl) fn(idx, nl);
}

// The outputs of up to L = 32 / sizeof(T) pairs of camera cam, Gaussians idx[0 .. nl), at once, one per lane (the
// lanes past nl repeat the last one and are not written): the exact path's formulas, operation for operation, as in
// backward_lanes, so that every lane rounds as the scalar code did; a pair it culls keeps its zeros.
template <typename T>
PR_LANES_CLONES void forward_lanes(const Camera<T>& cam, int64_t c, int64_t N, const int64_t* idx, int nl,
                                   const T* means, const T* quats, const T* scales, int64_t W, int64_t H, T near,
                                   T far, T eps2d, T* m2d, T* con, T* dep, int32_t* rad) {
  using V = typename Lanes<T>::type;
  const GaussianLanes<T, V> g(idx, nl, means, quats, scales);
  Pair<T, V> P;
  P.compute(cam, g.m, g.M, near, far, eps2d);
  const auto ok = P.det > 0;
  const V det_s = ok ? P.det : splat<V>(1);
  const V mid = T(0.5) * (P.a + P.c);
  const V lam = mid + sqrt_of(max_of(mid * mid - det_s, splat<V>(T(0.01))));
  const V root3 = 3 * sqrt_of(lam);
  const V u = cam.fx * P.p[0] / P.zs + cam.cx, v = cam.fy * P.p[1] / P.zs + cam.cy;
  const V con0 = P.c / det_s, con1 = -P.b / det_s, con2 = P.a / det_s;
  for (int i = 0; i < nl; ++i) {
    const T r = std::ceil(root3[i]);
    const bool on_image = u[i] + r > 0 && u[i] - r < W && v[i] + r > 0 && v[i] - r < H;
    if (!(P.z_ok[i] && ok[i] && on_image && std::isfinite(r))) continue;
    const int64_t cn = c * N + idx[i];
    m2d[cn * 2] = u[i]; m2d[cn * 2 + 1] = v[i];
    con[cn * 3] = con0[i]; con[cn * 3 + 1] = con1[i]; con[cn * 3 + 2] = con2[i];
    dep[cn] = P.p[2][i];
    rad[cn] = (int32_t)std::min(r, T(1 << 30));  // the cap keeps the conversion defined
  }
}

// A culled pair's outputs are all zero (gsplat's convention). Most pairs of a narrow view are culled, so the exact
// path (the covariance, its inverse and radius) runs only for the pairs that maybe_kept lets through, L at a time; a
// pair it stops would have been culled by the exact path too, so the radii are the same.
template <typename T>
void forward_impl(const T* means, const T* quats, const T* scales, const T* V, const T* K, int64_t C, int64_t N,
                  int64_t W, int64_t H, T near, T far, T eps2d, T* m2d, T* con, T* dep, int32_t* rad) {
  std::vector<Camera<T>> cams;
  for (int64_t c = 0; c < C; ++c) cams.emplace_back(V + c * 16, K + c * 9, W, H);
  constexpr int64_t CHUNK = 256;
  constexpr int L = 32 / sizeof(T);
  parallel_dealt(N, 2048, [&](int64_t b0, int64_t e0) {
    std::vector<uint8_t> maybe(CHUNK);
    for (int64_t n0 = b0; n0 < e0; n0 += CHUNK) {
      const int64_t len = std::min(CHUNK, e0 - n0);
      for (int64_t c = 0; c < C; ++c) {
        maybe_kept(cams[c], means, scales, n0, len, near, far, eps2d, (T)W, (T)H, maybe.data());
        // the chunk's rows of camera c are contiguous: zeroed in bulk (a culled pair's outputs), then the kept pairs
        // written; seven scalar stores per pair took half the forward's time at 330k Gaussians, 90 % culled
        const int64_t cn0 = c * N + n0;
        std::fill(m2d + cn0 * 2, m2d + (cn0 + len) * 2, T(0));
        std::fill(con + cn0 * 3, con + (cn0 + len) * 3, T(0));
        std::fill(dep + cn0, dep + cn0 + len, T(0));
        std::fill(rad + cn0, rad + cn0 + len, 0);
        in_lanes<L>(n0, n0 + len, [&](int64_t n) { return maybe[n - n0] != 0; }, [&](const int64_t* idx, int nl) {
          forward_lanes(cams[c], c, N, idx, nl, means, quats, scales, W, H, near, far, eps2d, m2d, con, dep, rad);
        });
      }
    }
  });
}

// The gradients of up to L = 32 / sizeof(T) Gaussians idx[0 .. nl) at once, one per lane of a GCC vector (the
// lanes past nl repeat the last one and are not written): the formulas operation for operation, with no multiply-add
// contracted, so that every lane rounds as scalar code of them would. A lane takes a camera's terms only where that
// pair was kept (radius > 0).
template <typename T>
PR_LANES_CLONES void backward_lanes(const std::vector<Camera<T>>& cams, int64_t N, const int64_t* idx, int nl, const T* means,
                    const T* quats, const T* scales, const int32_t* rad, const T* g_m2d, const T* g_con,
                    const T* g_dep, T near, T far, T eps2d, T* g_means, T* g_quats, T* g_scales) {
  using V = typename Lanes<T>::type;
  constexpr int L = 32 / sizeof(T);
  const V zero = {};
  const GaussianLanes<T, V> g(idx, nl, means, quats, scales);
  const V *M = g.M, *Rq = g.Rq, *qn = g.qn, &norm = g.norm;
  V gM[9], gm[3];
  for (int i = 0; i < 9; ++i) gM[i] = zero;
  for (int j = 0; j < 3; ++j) gm[j] = zero;
  for (int64_t c = 0; c < (int64_t)cams.size(); ++c) {
    decltype(V{} < V{}) kept;
    V q0, q1, q2, gu, gv, gd;
    bool any = false;
    for (int i = 0; i < L; ++i) {
      const int64_t cn = c * N + idx[std::min(i, nl - 1)];
      kept[i] = rad[cn] > 0 ? -1 : 0;
      any = any || rad[cn] > 0;
      q0[i] = g_con[cn * 3]; q1[i] = g_con[cn * 3 + 1]; q2[i] = g_con[cn * 3 + 2];
      gu[i] = g_m2d[cn * 2]; gv[i] = g_m2d[cn * 2 + 1]; gd[i] = g_dep[cn];
    }
    if (!any) continue;
    const Camera<T>& cam = cams[c];
    Pair<T, V> P;
    P.compute(cam, g.m, M, near, far, eps2d);  // z_ok and det > 0 hold in the kept lanes
    const V z = P.zs, a = P.a, b = P.b, cc = P.c, d2 = P.det * P.det;
    // conic (c, -b, a) / det  ->  a, b, c
    const V ga = (-cc * cc * q0 + b * cc * q1 - b * b * q2) / d2;
    const V gb = (2 * b * cc * q0 - (a * cc + b * b) * q1 + 2 * a * b * q2) / d2;
    const V gc = (-b * b * q0 + a * b * q1 - a * a * q2) / d2;
    V gA0[3], gA1[3], gT0[3] = {zero, zero, zero}, gT1[3] = {zero, zero, zero};
    for (int k = 0; k < 3; ++k) {
      gA0[k] = 2 * ga * P.A0[k] + gb * P.A1[k];
      gA1[k] = 2 * gc * P.A1[k] + gb * P.A0[k];
    }
    for (int i = 0; i < 3; ++i)
      for (int k = 0; k < 3; ++k) {  // A0_k = sum_i T0_i M_ik
        gT0[i] += gA0[k] * M[i * 3 + k];
        gT1[i] += gA1[k] * M[i * 3 + k];
        gM[i * 3 + k] = kept ? gM[i * 3 + k] + (P.T0[i] * gA0[k] + P.T1[i] * gA1[k]) : gM[i * 3 + k];
      }
    const T* R = cam.R;
    const V g00 = gT0[0] * R[0] + gT0[1] * R[1] + gT0[2] * R[2], g02 = gT0[0] * R[6] + gT0[1] * R[7] + gT0[2] * R[8];
    const V g11 = gT1[0] * R[3] + gT1[1] * R[4] + gT1[2] * R[5], g12 = gT1[0] * R[6] + gT1[1] * R[7] + gT1[2] * R[8];
    V gp[3] = {zero, zero, zero};
    // j00 = fx / z, j02 = -fx rx / z with rx = clamp(x / z) (no gradient where the clamp holds); same for y
    gp[2] += -cam.fx / (z * z) * g00 - cam.fy / (z * z) * g11 + cam.fx * P.rx / (z * z) * g02 + cam.fy * P.ry / (z * z) * g12;
    const V grx = -cam.fx / z * g02, gry = -cam.fy / z * g12;
    const V px = P.p[0] / z, py = P.p[1] / z;
    const auto in_x = (px > cam.lo_x) & (px < cam.hi_x), in_y = (py > cam.lo_y) & (py < cam.hi_y);
    gp[0] = in_x ? gp[0] + grx / z : gp[0];
    gp[2] = in_x ? gp[2] - grx * px / z : gp[2];
    gp[1] = in_y ? gp[1] + gry / z : gp[1];
    gp[2] = in_y ? gp[2] - gry * py / z : gp[2];
    // means2d = (fx x / z + cx, fy y / z + cy); depth = z
    gp[0] += gu * cam.fx / z; gp[1] += gv * cam.fy / z;
    gp[2] += -(gu * cam.fx * px + gv * cam.fy * py) / z + gd;
    for (int j = 0; j < 3; ++j) gm[j] = kept ? gm[j] + (R[j] * gp[0] + R[3 + j] * gp[1] + R[6 + j] * gp[2]) : gm[j];
  }
  // M = Rq diag(s)
  V gs[3], G[9];
  for (int k = 0; k < 3; ++k) gs[k] = gM[k] * Rq[k] + gM[3 + k] * Rq[3 + k] + gM[6 + k] * Rq[6 + k];
  for (int i = 0; i < 9; ++i) G[i] = gM[i] * g.s[i % 3];
  const V w = qn[0], x = qn[1], y = qn[2], z = qn[3];
  V gq[4];
  gq[0] = 2 * (-z * G[1] + y * G[2] + z * G[3] - x * G[5] - y * G[6] + x * G[7]);
  gq[1] = 2 * (y * G[1] + z * G[2] + y * G[3] - 2 * x * G[4] - w * G[5] + z * G[6] + w * G[7] - 2 * x * G[8]);
  gq[2] = 2 * (-2 * y * G[0] + x * G[1] + w * G[2] + x * G[3] + z * G[5] - w * G[6] + z * G[7] - 2 * y * G[8]);
  gq[3] = 2 * (-2 * z * G[0] - w * G[1] + x * G[2] + w * G[3] - 2 * z * G[4] + y * G[5] + x * G[6] + y * G[7]);
  const V dot = w * gq[0] + x * gq[1] + y * gq[2] + z * gq[3];  // through q / |q|
  for (int i = 0; i < nl; ++i) {
    const int64_t n = idx[i];
    for (int j = 0; j < 3; ++j) { g_means[n * 3 + j] = gm[j][i]; g_scales[n * 3 + j] = gs[j][i]; }
    if (!(norm[i] > T(1e-12))) continue;  // the identity stand-in has no gradient (its row stays zero)
    for (int k = 0; k < 4; ++k) g_quats[n * 4 + k] = (gq[k][i] - qn[k][i] * dot[i]) / norm[i];
  }
}

template <typename T>
void backward_impl(const T* means, const T* quats, const T* scales, const T* V, const T* K, const int32_t* rad,
                   const T* g_m2d, const T* g_con, const T* g_dep, int64_t C, int64_t N, int64_t W, int64_t H, T near,
                   T far, T eps2d, T* g_means, T* g_quats, T* g_scales) {
  std::vector<Camera<T>> cams;
  for (int64_t c = 0; c < C; ++c) cams.emplace_back(V + c * 16, K + c * 9, W, H);
  constexpr int L = 32 / sizeof(T);
  parallel_dealt(N, 2048, [&](int64_t b0, int64_t e0) {
    // a Gaussian culled by every camera gets no gradient: the chunk's rows are zeroed in bulk (the outputs are not
    // zero-filled first), then the others written, L at a time
    std::fill(g_means + b0 * 3, g_means + e0 * 3, T(0));
    std::fill(g_scales + b0 * 3, g_scales + e0 * 3, T(0));
    std::fill(g_quats + b0 * 4, g_quats + e0 * 4, T(0));
    auto any_kept = [&](int64_t n) {
      for (int64_t c = 0; c < C; ++c)
        if (rad[c * N + n] > 0) return true;
      return false;
    };
    in_lanes<L>(b0, e0, any_kept, [&](const int64_t* idx, int nl) {
      backward_lanes(cams, N, idx, nl, means, quats, scales, rad, g_m2d, g_con, g_dep, near, far, eps2d, g_means,
                     g_quats, g_scales);
    });
  });
}

}  // namespace

// -> means2d [C,N,2] (pixels), conics [C,N,3], depths [C,N] (camera z), radii [C,N] int32; all 0 where culled.
std::vector<torch::Tensor> project_forward(torch::Tensor means, torch::Tensor quats, torch::Tensor scales,
                                           torch::Tensor viewmats, torch::Tensor Ks, int64_t W, int64_t H,
                                           double near, double far, double eps2d) {
  const int64_t C = viewmats.size(0), N = means.size(0);
  auto o = means.options();
  auto m2d = torch::empty({C, N, 2}, o), con = torch::empty({C, N, 3}, o), dep = torch::empty({C, N}, o);
  auto rad = torch::empty({C, N}, o.dtype(torch::kInt32));
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "project_forward", [&] {
    forward_impl<scalar_t>(means.data_ptr<scalar_t>(), quats.data_ptr<scalar_t>(), scales.data_ptr<scalar_t>(),
                           viewmats.data_ptr<scalar_t>(), Ks.data_ptr<scalar_t>(), C, N, W, H, (scalar_t)near,
                           (scalar_t)far, (scalar_t)eps2d, m2d.data_ptr<scalar_t>(), con.data_ptr<scalar_t>(),
                           dep.data_ptr<scalar_t>(), rad.data_ptr<int32_t>());
  });
  return {m2d, con, dep, rad};
}

// Gradients w.r.t. means [N,3], quats [N,4], scales [N,3] from those of means2d, conics and depths.
std::vector<torch::Tensor> project_backward(torch::Tensor means, torch::Tensor quats, torch::Tensor scales,
                                            torch::Tensor viewmats, torch::Tensor Ks, torch::Tensor radii,
                                            torch::Tensor g_m2d, torch::Tensor g_con, torch::Tensor g_dep, int64_t W,
                                            int64_t H, double near, double far, double eps2d) {
  const int64_t C = viewmats.size(0), N = means.size(0);
  // every row is written by backward_impl: no zero-fill first (~1.8 ms a step at 330k Gaussians, 91 % culled)
  auto gm = torch::empty_like(means), gq = torch::empty_like(quats), gs = torch::empty_like(scales);
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "project_backward", [&] {
    backward_impl<scalar_t>(means.data_ptr<scalar_t>(), quats.data_ptr<scalar_t>(), scales.data_ptr<scalar_t>(),
                            viewmats.data_ptr<scalar_t>(), Ks.data_ptr<scalar_t>(), radii.data_ptr<int32_t>(),
                            g_m2d.data_ptr<scalar_t>(), g_con.data_ptr<scalar_t>(), g_dep.data_ptr<scalar_t>(), C, N, W,
                            H, (scalar_t)near, (scalar_t)far, (scalar_t)eps2d, gm.data_ptr<scalar_t>(),
                            gq.data_ptr<scalar_t>(), gs.data_ptr<scalar_t>());
  });
  return {gm, gq, gs};
}
