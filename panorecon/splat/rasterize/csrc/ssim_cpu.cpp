// SSIM of planar float32 images on the CPU, fused: the five local statistics are blurred separably with the
// Gaussian taps ('valid' region, no padding), the SSIM map and its three partial derivatives w.r.t. the statistics
// of x (mu_x, E[x^2], E[xy]; y is the constant target) are formed per pixel, and the backward applies the
// transposed blur to those partials ('full' region) and combines them with x and y. Same definition as
// losses.ssim_reference (C1 = 0.01^2, C2 = 0.03^2), which the tests compare with, values and gradients. Parallel
// over rows; float32 throughout (11-tap sums of values in [0, 1]). Every pass runs in CPU-picked clones (AVX-512,
// AVX2 + FMA, baseline) with its sums in registers, 64 columns at a time: 1.5 + 0.75 ms against 2.5-3.0 + 1.8-2.6 ms
// for the forward + backward at 256^2 x 3 when only the horizontal blur was cloned and the other passes, lambdas of
// at::parallel_for, ran in the baseline build (two threads, interleaved in one process, 2026-11-26).
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <cstring>
#include <memory>
#include <vector>

namespace {

constexpr float C1 = 0.01f * 0.01f, C2 = 0.03f * 0.03f;

#if defined(__x86_64__) && defined(__GNUC__)
// AVX-512 (x86-64-v4), AVX2 + FMA (x86-64-v3) and baseline builds; the loader picks by CPU
#define SSIM_CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
// the same, none of which contracts a multiply and an add into one rounding: outputs with the baseline build's bits
#define SSIM_EXACT_CLONES \
  __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default"), optimize("fp-contract=off")))
#else
#define SSIM_CLONES
#define SSIM_EXACT_CLONES
#endif

typedef float v16f __attribute__((vector_size(64)));  // 16 floats: one AVX-512 register, two AVX2, four SSE

// out[j .. j + 16 B) = sum over taps t (in order, from 0) of w[t] in[t][j ..]: B sums of 16 columns in registers, in
// flight together (one sum's taps are a chain of dependent adds).
template <int B>
__attribute__((always_inline)) inline void weighted_block(const float* const* in, const float* w, int64_t taps,
                                                          int64_t j, float* __restrict out) {
  v16f acc[B] = {};
  for (int64_t t = 0; t < taps; ++t)
    for (int u = 0; u < B; ++u) {
      v16f v;
      std::memcpy(&v, in[t] + j + 16 * u, sizeof v);  // unaligned load
      acc[u] += w[t] * v;
    }
  std::memcpy(out + j, acc, sizeof acc);
}

// out[j] = sum over taps t (in order, from 0) of w[t] in[t][j], for j < n: a vertical blur tap by tap, 64 columns at
// a time in registers instead of a pass over out per tap (the same sums, bit for bit, without contraction).
__attribute__((always_inline)) inline void weighted_rows(const float* const* in, const float* w, int64_t taps,
                                                         int64_t n, float* __restrict out) {
  int64_t j = 0;
  for (; j + 64 <= n; j += 64) weighted_block<4>(in, w, taps, j, out);
  for (; j + 16 <= n; j += 16) weighted_block<1>(in, w, taps, j, out);
  for (; j < n; ++j) {
    float acc = 0.f;
    for (int64_t t = 0; t < taps; ++t) acc += w[t] * in[t][j];
    out[j] = acc;
  }
}

// out[j] = sum_t g[t] in[j + t] for j < n: one row of the 'valid' blur (its multiply-adds contracted where the clone
// has FMA, as before weighted_rows); shifted: room for K pointers.
SSIM_CLONES void blur_row(const float* in, const float* g, int64_t K, int64_t n, float* out, const float** shifted) {
  for (int64_t t = 0; t < K; ++t) shifted[t] = in + t;
  weighted_rows(shifted, g, K, n, out);
}

// Output rows [b, e) of the forward (ro = p Ho + i): the vertical pass of the five statistics (rows: their
// horizontal pass, [5, P, H, Wo]), the SSIM map and its partials into pp [3, P, Ho, Wo], each row's map sum (in
// double, in column order) into row_sums. In clones of their own: as a lambda of at::parallel_for this ran in the
// baseline build, scalar (the row sum kept the map's five divisions out of vectors), and took 2/3 of the forward.
SSIM_EXACT_CLONES void map_rows(const float* __restrict rows, const float* __restrict g, int64_t K, int64_t P,
                                int64_t H, int64_t Ho, int64_t Wo, int64_t b, int64_t e, float* __restrict pp,
                                double* __restrict row_sums) {
  std::vector<float> st(5 * Wo), map(Wo);
  std::vector<const float*> in(K);
  float* __restrict sp = st.data();
  float* __restrict mp = map.data();
  for (int64_t ro = b; ro < e; ++ro) {
    const int64_t p = ro / Ho, i = ro % Ho;
    for (int k = 0; k < 5; ++k) {  // the vertical pass: rows i .. i + K - 1 of statistic k
      for (int64_t t = 0; t < K; ++t) in[t] = rows + (k * P * H + p * H + i + t) * Wo;
      weighted_rows(in.data(), g, K, Wo, sp + k * Wo);
    }
    float *__restrict d_mu = pp + (0 * P * Ho + ro) * Wo, *__restrict d_xx = pp + (1 * P * Ho + ro) * Wo,
          *__restrict d_xy = pp + (2 * P * Ho + ro) * Wo;
    for (int64_t j = 0; j < Wo; ++j) {
      const float mx = sp[j], my = sp[Wo + j], exx = sp[2 * Wo + j], eyy = sp[3 * Wo + j], exy = sp[4 * Wo + j];
      const float a1 = 2.f * mx * my + C1, a2 = 2.f * (exy - mx * my) + C2;
      const float b1 = mx * mx + my * my + C1, b2 = (exx - mx * mx) + (eyy - my * my) + C2;
      const float S = (a1 * a2) / (b1 * b2);
      mp[j] = S;
      d_mu[j] = S * (2.f * my / a1 - 2.f * my / a2 - 2.f * mx / b1 + 2.f * mx / b2);
      d_xx[j] = -S / b2;
      d_xy[j] = 2.f * S / a2;
    }
    double sum = 0.0;
    for (int64_t j = 0; j < Wo; ++j) sum += mp[j];
    row_sums[ro] = sum;
  }
}

// Rows [b, e) (r = p H + h) of the backward's column pass: the transposed ('full') vertical blur of the three
// partials pp [3, P, Ho, Wo] into cols [3, P, H, Wo]. Clones of its own, as map_rows.
SSIM_EXACT_CLONES void transposed_columns(const float* __restrict pp, const float* __restrict g, int64_t K, int64_t P,
                                          int64_t H, int64_t Ho, int64_t Wo, int64_t b, int64_t e,
                                          float* __restrict cols) {
  std::vector<const float*> in(K);
  for (int64_t r = b; r < e; ++r) {  // row h of plane p gathers the output rows h - t, t < K, inside [0, Ho)
    const int64_t p = r / H, h = r % H;
    const int64_t t0 = std::max<int64_t>(0, h - Ho + 1), t1 = std::min<int64_t>(K - 1, h);
    for (int k = 0; k < 3; ++k) {
      for (int64_t t = t0; t <= t1; ++t) in[t - t0] = pp + (k * P * Ho + p * Ho + h - t) * Wo;
      weighted_rows(in.data(), g + t0, t1 - t0 + 1, Wo, cols + (k * P * H + r) * Wo);
    }
  }
}

// Rows [b, e) of the backward's row pass: the transposed horizontal blur of cols, combined with x and y into the
// gradient, s (T(d_mu) + 2 x T(d_xx) + y T(d_xy)). Clones of its own, as map_rows.
SSIM_EXACT_CLONES void transposed_rows(const float* __restrict cols, const float* __restrict x,
                                       const float* __restrict y, const float* __restrict g, int64_t K, int64_t P,
                                       int64_t H, int64_t W, int64_t Wo, float s, int64_t b, int64_t e,
                                       float* __restrict grad) {
  std::vector<float> full(3 * W);
  float* __restrict fp = full.data();
  for (int64_t r = b; r < e; ++r) {
    for (int k = 0; k < 3; ++k) {  // column q gathers the output columns q - t, t < K, inside [0, Wo)
      const float* __restrict in = cols + (k * P * H + r) * Wo;
      float* __restrict out = fp + k * W;
      for (int64_t q = 0; q < W; ++q) out[q] = 0.f;
      for (int64_t t = 0; t < K; ++t) {
        const float w = g[t];
        for (int64_t j = 0; j < Wo; ++j) out[j + t] += w * in[j];
      }
    }
    const float *__restrict xr = x + r * W, *__restrict yr = y + r * W;
    float* __restrict gr = grad + r * W;
    for (int64_t q = 0; q < W; ++q) gr[q] = s * (fp[q] + 2.f * xr[q] * fp[W + q] + yr[q] * fp[2 * W + q]);
  }
}

}  // namespace

// x, y [P, H, W] contiguous float32 planes (P = images x channels), taps g [K] -> {ssim_map_mean (scalar),
// partials [3, P, H - K + 1, W - K + 1]: dS/dmu_x, dS/dE[x^2], dS/dE[xy] per output pixel}.
std::vector<torch::Tensor> ssim_forward(torch::Tensor x, torch::Tensor y, torch::Tensor g) {
  TORCH_CHECK(x.dim() == 3 && x.sizes() == y.sizes(), "ssim_forward: x and y must be [P, H, W] of one shape");
  const int64_t P = x.size(0), H = x.size(1), W = x.size(2), K = g.size(0), Ho = H - K + 1, Wo = W - K + 1;
  TORCH_CHECK(Ho > 0 && Wo > 0, "ssim_forward: images of ", H, "x", W, " are smaller than the ", K, "-tap window");
  const float *px = x.data_ptr<float>(), *py = y.data_ptr<float>(), *pg = g.data_ptr<float>();
  // the horizontal pass of the five statistics, [5, P, H, Wo] (every entry written: no zero-fill first)
  std::unique_ptr<float[]> rows(new float[5 * P * H * Wo]);
  at::parallel_for(0, P * H, 16, [&](int64_t b, int64_t e) {
    std::vector<float> s(3 * W);
    std::vector<const float*> shifted(K);
    for (int64_t r = b; r < e; ++r) {
      const float *xr = px + r * W, *yr = py + r * W;
      for (int64_t j = 0; j < W; ++j) {
        s[j] = xr[j] * xr[j]; s[W + j] = yr[j] * yr[j]; s[2 * W + j] = xr[j] * yr[j];
      }
      const float* src[5] = {xr, yr, s.data(), s.data() + W, s.data() + 2 * W};
      for (int k = 0; k < 5; ++k) blur_row(src[k], pg, K, Wo, rows.get() + (k * P * H + r) * Wo, shifted.data());
    }
  });
  auto partials = torch::empty({3, P, Ho, Wo}, x.options());
  float* pp = partials.data_ptr<float>();
  const int64_t n_out = P * Ho;
  std::vector<double> row_sums(n_out);
  at::parallel_for(0, n_out, 8, [&](int64_t b, int64_t e) {
    map_rows(rows.get(), pg, K, P, H, Ho, Wo, b, e, pp, row_sums.data());
  });
  double total = 0.0;
  for (double s : row_sums) total += s;
  return {torch::tensor(total / double(n_out * Wo), x.options()), partials};
}

// dL/dx [P, H, W] given g_mean = dL/d(mean of the SSIM map), a scalar tensor (read here, not in Python, so that the
// training loop reads nothing back between steps): s (T(d_mu) + 2 x T(d_xx) + y T(d_xy)) with s = g_mean / the map's
// size and T the transposed ('full') blur, separably: columns first into [3, P, H, Wo], then rows.
torch::Tensor ssim_backward(torch::Tensor x, torch::Tensor y, torch::Tensor g, torch::Tensor partials,
                            torch::Tensor g_mean) {
  const int64_t P = x.size(0), H = x.size(1), W = x.size(2), K = g.size(0), Ho = H - K + 1, Wo = W - K + 1;
  const float *px = x.data_ptr<float>(), *py = y.data_ptr<float>(), *pg = g.data_ptr<float>();
  const float* pp = partials.data_ptr<float>();
  std::unique_ptr<float[]> cols(new float[3 * P * H * Wo]);  // every entry written: no zero-fill first
  at::parallel_for(0, P * H, 16, [&](int64_t b, int64_t e) {
    transposed_columns(pp, pg, K, P, H, Ho, Wo, b, e, cols.get());
  });
  auto grad = torch::empty_like(x);
  const float s = g_mean.item<float>() / float(P * Ho * Wo);
  at::parallel_for(0, P * H, 16, [&](int64_t b, int64_t e) {
    transposed_rows(cols.get(), px, py, pg, K, P, H, W, Wo, s, b, e, grad.data_ptr<float>());
  });
  return grad;
}
