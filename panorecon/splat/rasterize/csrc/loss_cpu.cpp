// The training loss's L1 and depth terms on the CPU (splat/losses.py), each a pass or two over the pixels where
// PyTorch took a dozen elementwise operations and reductions each way (~0.7 ms for L1 and ~1.9 ms for the Pearson
// term at 256^2, forward + backward, two threads). Sums in double, over fixed chunks added in chunk order, so a
// value is the same whatever the thread count.
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

namespace {
constexpr int64_t CHUNK = 4096;  // pixels per partial sum

// Sums fn(i) (an array of K doubles) over [0, n): per chunk in parallel, then the chunks in order.
template <int K, typename Fn>
std::array<double, K> chunked_sum(int64_t n, const Fn& fn) {
  const int64_t chunks = (n + CHUNK - 1) / CHUNK;
  std::vector<std::array<double, K>> part(chunks);
  at::parallel_for(0, chunks, 1, [&](int64_t b, int64_t e) {
    for (int64_t c = b; c < e; ++c) {
      std::array<double, K> s{};
      for (int64_t i = c * CHUNK, end = std::min(n, (c + 1) * CHUNK); i < end; ++i) fn(i, s);
      part[c] = s;
    }
  });
  std::array<double, K> total{};
  for (const auto& s : part)
    for (int k = 0; k < K; ++k) total[k] += s[k];
  return total;
}

// Whether pixel i counts in the Pearson term: inside the mask (none: all) and both depths finite.
inline bool counts(const bool* valid, const float* x, const float* y, int64_t i) {
  return (!valid || valid[i]) && std::isfinite(x[i]) && std::isfinite(y[i]);
}

void check_pair(const torch::Tensor& x, const torch::Tensor& y, const char* what) {
  TORCH_CHECK(x.dtype() == torch::kFloat32 && y.dtype() == torch::kFloat32, what, ": float32 inputs expected");
  TORCH_CHECK(x.sizes() == y.sizes(), what, ": inputs of one shape expected, got ", x.sizes(), " and ", y.sizes());
  TORCH_CHECK(x.is_contiguous() && y.is_contiguous(), what, ": contiguous inputs expected");
}
}  // namespace

// mean |x - y| over all elements -> 0-dim float32 (summed in double)
torch::Tensor l1_forward(torch::Tensor x, torch::Tensor y) {
  check_pair(x, y, "l1_forward");
  const float *px = x.data_ptr<float>(), *py = y.data_ptr<float>();
  const int64_t n = x.numel();
  const auto s = chunked_sum<1>(n, [&](int64_t i, std::array<double, 1>& a) { a[0] += std::fabs(px[i] - py[i]); });
  return torch::tensor((float)(s[0] / (double)std::max<int64_t>(n, 1)), x.options());
}

// Gradient w.r.t. x of l1_forward times g_loss: (g / n) sgn(x - y), rounded as PyTorch's backward of
// (x - y).abs().mean() (mean: g / n in float32; abs: times sgn), so the two give the same bits.
torch::Tensor l1_backward(torch::Tensor x, torch::Tensor y, torch::Tensor g_loss) {
  check_pair(x, y, "l1_backward");
  const float c = g_loss.item<float>() / (float)x.numel();
  auto out = torch::empty_like(x);
  const float *px = x.data_ptr<float>(), *py = y.data_ptr<float>();
  float* po = out.data_ptr<float>();
  at::parallel_for(0, x.numel(), 16384, [&](int64_t b, int64_t e) {
    for (int64_t i = b; i < e; ++i) {
      const float d = px[i] - py[i];
      po[i] = c * (float)((d > 0.f) - (d < 0.f));  // sgn, 0 for a NaN as torch.sgn
    }
  });
  return out;
}

// 1 - Pearson correlation of x (rendered depth) and y (teacher depth) over the pixels where valid (a bool mask of
// their shape, or empty: all) and both are finite; 0 with fewer than 2 such pixels or when Sxx Syy <= 1e-24.
// -> [loss (0-dim float32), stats (float64: n, mean x, mean y, Sxx, Syy, Sxy, used, corr)]
std::vector<torch::Tensor> pearson_forward(torch::Tensor x, torch::Tensor y, torch::Tensor valid) {
  check_pair(x, y, "pearson_forward");
  TORCH_CHECK(valid.numel() == 0 || (valid.dtype() == torch::kBool && valid.sizes() == x.sizes() &&
                                      valid.is_contiguous()),
              "pearson_forward: valid must be empty or a contiguous bool mask of the depths' shape ", x.sizes());
  const float *px = x.data_ptr<float>(), *py = y.data_ptr<float>();
  const bool* pv = valid.numel() ? valid.data_ptr<bool>() : nullptr;
  const int64_t N = x.numel();
  const auto s1 = chunked_sum<3>(N, [&](int64_t i, std::array<double, 3>& a) {
    if (counts(pv, px, py, i)) { a[0] += 1.0; a[1] += px[i]; a[2] += py[i]; }
  });
  const double n = s1[0], mx = s1[1] / std::max(n, 1.0), my = s1[2] / std::max(n, 1.0);
  const auto s2 = chunked_sum<3>(N, [&](int64_t i, std::array<double, 3>& a) {
    if (counts(pv, px, py, i)) {
      const double dx = px[i] - mx, dy = py[i] - my;
      a[0] += dx * dx; a[1] += dy * dy; a[2] += dx * dy;
    }
  });
  const double sxx = s2[0], syy = s2[1], sxy = s2[2];
  const bool used = n >= 2 && sxx * syy > 1e-24;
  const double corr = used ? sxy / std::sqrt(sxx * syy) : 0.0;
  auto stats = torch::tensor({n, mx, my, sxx, syy, sxy, used ? 1.0 : 0.0, corr}, torch::dtype(torch::kFloat64));
  return {torch::tensor((float)(used ? 1.0 - corr : 0.0), x.options()), stats};
}

// Gradient w.r.t. x of pearson_forward's loss times g_loss: -g (dy / sqrt(Sxx Syy) - corr dx / Sxx) at the pixels
// that count, 0 elsewhere (and everywhere when the loss was 0 by rule).
torch::Tensor pearson_backward(torch::Tensor x, torch::Tensor y, torch::Tensor valid, torch::Tensor stats,
                               torch::Tensor g_loss) {
  check_pair(x, y, "pearson_backward");
  const double* st = stats.data_ptr<double>();
  const double mx = st[1], my = st[2], sxx = st[3], syy = st[4], used = st[6], corr = st[7];
  const double g = g_loss.item<double>();
  auto out = torch::zeros_like(x);
  if (used == 0.0) return out;
  const float *px = x.data_ptr<float>(), *py = y.data_ptr<float>();
  const bool* pv = valid.numel() ? valid.data_ptr<bool>() : nullptr;
  float* po = out.data_ptr<float>();
  const double inv_root = 1.0 / std::sqrt(sxx * syy), corr_sxx = corr / sxx;
  at::parallel_for(0, x.numel(), 16384, [&](int64_t b, int64_t e) {
    for (int64_t i = b; i < e; ++i)
      if (counts(pv, px, py, i)) po[i] = (float)(-g * ((py[i] - my) * inv_root - (px[i] - mx) * corr_sxx));
  });
  return out;
}
