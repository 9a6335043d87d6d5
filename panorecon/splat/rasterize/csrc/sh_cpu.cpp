// Spherical-harmonic colours of the Gaussians a camera sees, on the CPU: forward and hand-written backward,
// parallel over Gaussians. The same arithmetic as the PyTorch reference (sh.py: sh_to_rgb with directions
// normalised as (mean - camera centre) / max(|mean - camera centre|, 1e-12)): colour = sum_k basis_k(dir)
// coeff_k + 0.5, clamped at 0. Only pairs with radius > 0 are evaluated (the compositor reads no other); a culled
// pair's colour is 0 and passes no gradient. The DC band and the higher bands come as two tensors (the model's
// sh0 and shN: no per-step concatenation). Templated on the scalar type (float for training, double for tests).
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <cmath>
#include <vector>

namespace {

constexpr double C0 = 0.28209479177387814, C1 = 0.4886025119029199;
constexpr double C2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
                          0.5462742152960396};
constexpr double C3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
                          -0.4570457994644658, 1.445305721320277, -0.5900435899266435};

// basis [K] at the unit direction (x, y, z); with ``grad`` also d basis_k / d(x, y, z) [K][3].
template <typename T>
inline void sh_basis(int degree, T x, T y, T z, T* b, T (*d)[3]) {
  b[0] = T(C0);
  if (d) d[0][0] = d[0][1] = d[0][2] = 0;
  if (degree < 1) return;
  b[1] = -T(C1) * y; b[2] = T(C1) * z; b[3] = -T(C1) * x;
  if (d) {
    for (int k = 1; k < 4; ++k) d[k][0] = d[k][1] = d[k][2] = 0;
    d[1][1] = -T(C1); d[2][2] = T(C1); d[3][0] = -T(C1);
  }
  if (degree < 2) return;
  const T xx = x * x, yy = y * y, zz = z * z;
  b[4] = T(C2[0]) * x * y; b[5] = T(C2[1]) * y * z; b[6] = T(C2[2]) * (2 * zz - xx - yy);
  b[7] = T(C2[3]) * x * z; b[8] = T(C2[4]) * (xx - yy);
  if (d) {
    const T g[5][3] = {{y, x, 0}, {0, z, y}, {-2 * x, -2 * y, 4 * z}, {z, 0, x}, {2 * x, -2 * y, 0}};
    for (int k = 0; k < 5; ++k)
      for (int j = 0; j < 3; ++j) d[4 + k][j] = T(C2[k]) * g[k][j];
  }
  if (degree < 3) return;
  b[9] = T(C3[0]) * y * (3 * xx - yy);
  b[10] = T(C3[1]) * x * y * z;
  b[11] = T(C3[2]) * y * (4 * zz - xx - yy);
  b[12] = T(C3[3]) * z * (2 * zz - 3 * xx - 3 * yy);
  b[13] = T(C3[4]) * x * (4 * zz - xx - yy);
  b[14] = T(C3[5]) * z * (xx - yy);
  b[15] = T(C3[6]) * x * (xx - 3 * yy);
  if (d) {
    const T g[7][3] = {{6 * x * y, 3 * xx - 3 * yy, 0},
                       {y * z, x * z, x * y},
                       {-2 * x * y, 4 * zz - xx - 3 * yy, 8 * y * z},
                       {-6 * x * z, -6 * y * z, 6 * zz - 3 * xx - 3 * yy},
                       {4 * zz - 3 * xx - yy, -2 * x * y, 8 * x * z},
                       {2 * x * z, -2 * y * z, xx - yy},
                       {3 * xx - 3 * yy, -6 * x * y, 0}};
    for (int k = 0; k < 7; ++k)
      for (int j = 0; j < 3; ++j) d[9 + k][j] = T(C3[k]) * g[k][j];
  }
}

// Unnormalised direction v = mean - camera centre, its clamped norm, and the unit direction.
template <typename T>
inline T direction(const T* mean, const T* campos, T* v, T* u) {
  for (int j = 0; j < 3; ++j) v[j] = mean[j] - campos[j];
  const T norm = std::max(std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]), T(1e-12));
  for (int j = 0; j < 3; ++j) u[j] = v[j] / norm;
  return norm;
}

// The coefficients of Gaussian n, in two parts so that the model's DC band and higher bands need no
// concatenation: k = 0 at dc[n * sd + ch], k >= 1 at rest[n * sr + (k - 1) * 3 + ch] (sd, sr: row strides).
template <typename T>
struct Coeffs {
  const T* dc;
  const T* rest;
  int64_t sd, sr;
  inline T operator()(int64_t n, int k, int ch) const {
    return k == 0 ? dc[n * sd + ch] : rest[n * sr + (k - 1) * 3 + ch];
  }
};

#if defined(__x86_64__) && defined(__GNUC__)
// AVX-512, AVX2 and baseline builds, none of which contracts a multiply and an add: each rounds as the general loop
#define SH_CLONES \
  __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default"), optimize("fp-contract=off")))
#else
#define SH_CLONES
#endif

// Degree 0, the trainer's default (the colour reads neither the view direction nor the higher bands): camera c's
// colours of Gaussians [b, e), 0.5 + C0 dc clamped at 0, and 0 where culled, in clones of its own (the general loop, a
// lambda of at::parallel_for, ran in the baseline build with its basis and coefficient lookups per pair). The same
// arithmetic as the general loop. GCC keeps this loop scalar (the row stride sd is a run-time value).
template <typename T>
SH_CLONES void forward_dc(const T* __restrict dc, int64_t sd, const int32_t* __restrict rad, int64_t b, int64_t e,
                          T* __restrict out) {
  for (int64_t n = b; n < e; ++n) {
    const bool seen = rad[n] > 0;
    for (int ch = 0; ch < 3; ++ch) {
      T s = T(0.5);
      s += T(C0) * dc[n * sd + ch];
      out[n * 3 + ch] = seen && s > 0 ? s : T(0);
    }
  }
}

// Degree 0's gradient of the DC band for Gaussians [b, e): C0 times the colour gradients of the pairs that see it
// with a colour sum >= 0, summed over the cameras in order from 0 onto zeros (as the general loop adds them).
template <typename T>
SH_CLONES void backward_dc(const T* __restrict dc, int64_t sd, const int32_t* __restrict rad,
                           const T* __restrict g_colors, int64_t C, int64_t N, int64_t b, int64_t e, T* __restrict g_dc) {
  for (int64_t i = b * 3; i < e * 3; ++i) g_dc[i] = T(0);
  for (int64_t c = 0; c < C; ++c)
    for (int64_t n = b; n < e; ++n) {
      if (rad[c * N + n] <= 0) continue;  // most pairs of a narrow view: a branch that skips them is well predicted
      for (int ch = 0; ch < 3; ++ch) {
        T s = T(0.5);
        s += T(C0) * dc[n * sd + ch];
        const T graw = s >= 0 ? g_colors[(c * N + n) * 3 + ch] : T(0);
        g_dc[n * 3 + ch] += T(C0) * graw;
      }
    }
}

template <typename T>
void forward_impl(Coeffs<T> co, const T* means, const T* campos, const int32_t* rad, int64_t C, int64_t N,
                  int degree, T* colors) {
  const int k_used = (degree + 1) * (degree + 1);
  if (degree == 0) {
    for (int64_t c = 0; c < C; ++c)
      at::parallel_for(0, N, 4096, [&](int64_t b0, int64_t e0) {
        forward_dc(co.dc, co.sd, rad + c * N, b0, e0, colors + c * N * 3);
      });
    return;
  }
  at::parallel_for(0, N, 4096, [&](int64_t b0, int64_t e0) {
    T b[16], v[3], u[3];
    for (int64_t n = b0; n < e0; ++n) {
      for (int64_t c = 0; c < C; ++c) {
        T* out = colors + (c * N + n) * 3;
        if (rad[c * N + n] <= 0) { out[0] = out[1] = out[2] = 0; continue; }
        if (degree > 0) direction(means + n * 3, campos + c * 3, v, u);
        sh_basis<T>(degree, u[0], u[1], u[2], b, nullptr);
        for (int ch = 0; ch < 3; ++ch) {
          T s = T(0.5);
          for (int k = 0; k < k_used; ++k) s += b[k] * co(n, k, ch);
          out[ch] = s > 0 ? s : T(0);
        }
      }
    }
  });
}

// Writes every row of g_dc [N,1,3], g_rest [N,K-1,3] (contiguous) and, above degree 0, g_means [N,3]: each
// Gaussian's rows are zeroed and summed over its cameras by one thread (no zero-fill of the outputs first: at degree 0
// and 330k Gaussians that was ~0.3 ms a step). Degree 0 (backward_dc) writes g_dc alone: its colour ignores the view
// direction and the higher bands.
template <typename T>
void backward_impl(Coeffs<T> co, const T* means, const T* campos, const int32_t* rad, const T* g_colors,
                   int64_t C, int64_t N, int64_t K, int degree, T* g_dc, T* g_rest, T* g_means) {
  const int k_used = (degree + 1) * (degree + 1);
  if (degree == 0) {  // g_rest is [N, 0, 3] and g_means [0, 3]
    at::parallel_for(0, N, 4096, [&](int64_t b0, int64_t e0) {
      backward_dc(co.dc, co.sd, rad, g_colors, C, N, b0, e0, g_dc);
    });
    return;
  }
  at::parallel_for(0, N, 4096, [&](int64_t b0, int64_t e0) {
    T b[16], d[16][3], v[3], u[3];
    for (int64_t n = b0; n < e0; ++n) {
      std::fill(g_dc + n * 3, g_dc + n * 3 + 3, T(0));
      std::fill(g_rest + n * (K - 1) * 3, g_rest + (n + 1) * (K - 1) * 3, T(0));
      std::fill(g_means + n * 3, g_means + n * 3 + 3, T(0));
      for (int64_t c = 0; c < C; ++c) {
        if (rad[c * N + n] <= 0) continue;
        const T norm = direction(means + n * 3, campos + c * 3, v, u);
        sh_basis<T>(degree, u[0], u[1], u[2], b, d);
        T graw[3];
        for (int ch = 0; ch < 3; ++ch) {  // clamp at 0 passes the gradient where the sum is >= 0
          T s = T(0.5);
          for (int k = 0; k < k_used; ++k) s += b[k] * co(n, k, ch);
          graw[ch] = s >= 0 ? g_colors[(c * N + n) * 3 + ch] : T(0);
        }
        T gu[3] = {0, 0, 0};
        for (int k = 0; k < k_used; ++k) {
          T* gco = k == 0 ? g_dc + n * 3 : g_rest + (n * (K - 1) + k - 1) * 3;
          T gb = 0;
          for (int ch = 0; ch < 3; ++ch) {
            gco[ch] += b[k] * graw[ch];
            gb += co(n, k, ch) * graw[ch];
          }
          for (int j = 0; j < 3; ++j) gu[j] += gb * d[k][j];
        }
        // u = v / max(|v|, 1e-12): the projection (I - u u^T) / |v| above the clamp, 1 / 1e-12 below it
        const bool clamped = !(norm > T(1e-12));
        const T dot = clamped ? T(0) : u[0] * gu[0] + u[1] * gu[1] + u[2] * gu[2];
        for (int j = 0; j < 3; ++j) g_means[n * 3 + j] += (gu[j] - u[j] * dot) / norm;
      }
    }
  });
}

}  // namespace

namespace {
// dc [N,1,3] and rest [N,K-1,3], each with unit strides inside a row (any row stride: views of one [N,K,3] do).
template <typename T>
Coeffs<T> coeffs_of(const torch::Tensor& dc, const torch::Tensor& rest) {
  TORCH_CHECK(dc.dim() == 3 && dc.size(1) == 1 && dc.size(2) == 3 && dc.stride(2) == 1,
              "sh: dc must be [N,1,3] with unit channel stride");
  TORCH_CHECK(rest.dim() == 3 && rest.size(2) == 3 && rest.size(0) == dc.size(0) &&
                  (rest.size(1) == 0 || (rest.stride(2) == 1 && rest.stride(1) == 3)),
              "sh: rest must be [N,K-1,3] with rows of unit stride");
  return {dc.data_ptr<T>(), rest.data_ptr<T>(), dc.stride(0), rest.stride(0)};
}
}  // namespace

// -> colours [C,N,3] of coefficients dc [N,1,3] + rest [N,K-1,3] (K >= (degree + 1)^2) seen from camera centres
// campos [C,3].
torch::Tensor sh_forward(torch::Tensor dc, torch::Tensor rest, torch::Tensor means, torch::Tensor campos,
                         torch::Tensor radii, int64_t degree) {
  const int64_t C = campos.size(0), N = means.size(0);
  TORCH_CHECK(rest.size(1) + 1 >= (degree + 1) * (degree + 1), "sh_forward: too few coefficients for the degree");
  auto colors = torch::empty({C, N, 3}, means.options());
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "sh_forward", [&] {
    forward_impl<scalar_t>(coeffs_of<scalar_t>(dc, rest), means.data_ptr<scalar_t>(), campos.data_ptr<scalar_t>(),
                           radii.data_ptr<int32_t>(), C, N, (int)degree, colors.data_ptr<scalar_t>());
  });
  return colors;
}

// Gradients w.r.t. dc [N,1,3], rest [N,K-1,3] (contiguous; [N,0,3] at degree 0) and means [N,3] ([0,3] at degree 0:
// the colour does not depend on the view direction) from those of the colours [C,N,3].
std::vector<torch::Tensor> sh_backward(torch::Tensor dc, torch::Tensor rest, torch::Tensor means,
                                       torch::Tensor campos, torch::Tensor radii, torch::Tensor g_colors,
                                       int64_t degree) {
  const int64_t C = campos.size(0), N = means.size(0), K = rest.size(1) + 1;
  // degree 0 reads no higher band: no [N, K-1, 3] of zeros for them (the caller passes None back instead)
  const int64_t K_out = degree > 0 ? K : 1;
  auto g_dc = torch::empty({N, 1, 3}, means.options());
  auto g_rest = torch::empty({N, K_out - 1, 3}, means.options());
  auto g_means = torch::empty({degree > 0 ? N : 0, 3}, means.options());
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "sh_backward", [&] {
    backward_impl<scalar_t>(coeffs_of<scalar_t>(dc, rest), means.data_ptr<scalar_t>(), campos.data_ptr<scalar_t>(),
                            radii.data_ptr<int32_t>(), g_colors.data_ptr<scalar_t>(), C, N, K_out, (int)degree,
                            g_dc.data_ptr<scalar_t>(), g_rest.data_ptr<scalar_t>(), g_means.data_ptr<scalar_t>());
  });
  return {g_dc, g_rest, g_means};
}
