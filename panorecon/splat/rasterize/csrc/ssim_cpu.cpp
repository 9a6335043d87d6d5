// SSIM of planar float32 images on the CPU, fused: the five local statistics are blurred separably with the
// Gaussian taps ('valid' region, no padding), the SSIM map and its three partial derivatives w.r.t. the statistics
// of x (mu_x, E[x^2], E[xy]; y is the constant target) are formed per pixel, and the backward applies the
// transposed blur to those partials ('full' region) and combines them with x and y. Same definition as
// losses.ssim_reference (C1 = 0.01^2, C2 = 0.03^2), which the tests compare with, values and gradients. Parallel
// over rows; float32 throughout (11-tap sums of values in [0, 1]).
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <vector>

namespace {

constexpr float C1 = 0.01f * 0.01f, C2 = 0.03f * 0.03f;

#if defined(__x86_64__) && defined(__GNUC__)
// AVX-512 (x86-64-v4), AVX2 + FMA (x86-64-v3) and baseline builds, bit-identical; the loader picks by CPU
#define SSIM_CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define SSIM_CLONES
#endif

// out[j] (+)= sum_t g[t] in[j + t] for j < n: one row of the 'valid' blur.
SSIM_CLONES void blur_row(const float* in, const float* g, int64_t K, int64_t n, float* out) {
  for (int64_t j = 0; j < n; ++j) out[j] = 0.f;
  for (int64_t t = 0; t < K; ++t) {
    const float w = g[t];
    for (int64_t j = 0; j < n; ++j) out[j] += w * in[j + t];
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
  // the horizontal pass of the five statistics, [5, P, H, Wo]
  std::vector<float> rows(5 * P * H * Wo);
  at::parallel_for(0, P * H, 16, [&](int64_t b, int64_t e) {
    std::vector<float> s(3 * W);
    for (int64_t r = b; r < e; ++r) {
      const float *xr = px + r * W, *yr = py + r * W;
      for (int64_t j = 0; j < W; ++j) {
        s[j] = xr[j] * xr[j]; s[W + j] = yr[j] * yr[j]; s[2 * W + j] = xr[j] * yr[j];
      }
      const float* src[5] = {xr, yr, s.data(), s.data() + W, s.data() + 2 * W};
      for (int k = 0; k < 5; ++k) blur_row(src[k], pg, K, Wo, rows.data() + (k * P * H + r) * Wo);
    }
  });
  auto partials = torch::empty({3, P, Ho, Wo}, x.options());
  float* pp = partials.data_ptr<float>();
  const int64_t n_out = P * Ho;
  std::vector<double> row_sums(n_out);
  at::parallel_for(0, n_out, 8, [&](int64_t b, int64_t e) {
    std::vector<float> st(5 * Wo), col(H);
    for (int64_t ro = b; ro < e; ++ro) {
      const int64_t p = ro / Ho, i = ro % Ho;
      for (int k = 0; k < 5; ++k) {  // the vertical pass: rows i .. i + K - 1 of statistic k
        float* out = st.data() + k * Wo;
        for (int64_t j = 0; j < Wo; ++j) out[j] = 0.f;
        for (int64_t t = 0; t < K; ++t) {
          const float* in = rows.data() + (k * P * H + p * H + i + t) * Wo;
          const float w = pg[t];
          for (int64_t j = 0; j < Wo; ++j) out[j] += w * in[j];
        }
      }
      double sum = 0.0;
      float *d_mu = pp + (0 * P * Ho + ro) * Wo, *d_xx = pp + (1 * P * Ho + ro) * Wo, *d_xy = pp + (2 * P * Ho + ro) * Wo;
      for (int64_t j = 0; j < Wo; ++j) {
        const float mx = st[j], my = st[Wo + j], exx = st[2 * Wo + j], eyy = st[3 * Wo + j], exy = st[4 * Wo + j];
        const float a1 = 2.f * mx * my + C1, a2 = 2.f * (exy - mx * my) + C2;
        const float b1 = mx * mx + my * my + C1, b2 = (exx - mx * mx) + (eyy - my * my) + C2;
        const float S = (a1 * a2) / (b1 * b2);
        sum += S;
        d_mu[j] = S * (2.f * my / a1 - 2.f * my / a2 - 2.f * mx / b1 + 2.f * mx / b2);
        d_xx[j] = -S / b2;
        d_xy[j] = 2.f * S / a2;
      }
      row_sums[ro] = sum;
    }
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
  std::vector<float> cols(3 * P * H * Wo);
  at::parallel_for(0, P * H, 16, [&](int64_t b, int64_t e) {
    for (int64_t r = b; r < e; ++r) {  // row h of plane p gathers the output rows h - t, t < K, inside [0, Ho)
      const int64_t p = r / H, h = r % H;
      for (int k = 0; k < 3; ++k) {
        float* out = cols.data() + (k * P * H + r) * Wo;
        for (int64_t j = 0; j < Wo; ++j) out[j] = 0.f;
        for (int64_t t = std::max<int64_t>(0, h - Ho + 1); t <= std::min<int64_t>(K - 1, h); ++t) {
          const float* in = pp + (k * P * Ho + p * Ho + h - t) * Wo;
          const float w = pg[t];
          for (int64_t j = 0; j < Wo; ++j) out[j] += w * in[j];
        }
      }
    }
  });
  auto grad = torch::empty_like(x);
  float* pgx = grad.data_ptr<float>();
  const float s = g_mean.item<float>() / float(P * Ho * Wo);
  at::parallel_for(0, P * H, 16, [&](int64_t b, int64_t e) {
    std::vector<float> full(3 * W);
    for (int64_t r = b; r < e; ++r) {
      for (int k = 0; k < 3; ++k) {  // column q gathers the output columns q - t, t < K, inside [0, Wo)
        const float* in = cols.data() + (k * P * H + r) * Wo;
        float* out = full.data() + k * W;
        for (int64_t q = 0; q < W; ++q) out[q] = 0.f;
        for (int64_t t = 0; t < K; ++t) {
          const float w = pg[t];
          for (int64_t j = 0; j < Wo; ++j) out[j + t] += w * in[j];
        }
      }
      const float *xr = px + r * W, *yr = py + r * W;
      float* gr = pgx + r * W;
      for (int64_t q = 0; q < W; ++q) gr[q] = s * (full[q] + 2.f * xr[q] * full[W + q] + yr[q] * full[2 * W + q]);
    }
  });
  return grad;
}
