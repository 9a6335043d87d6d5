// DefaultStrategy's densification statistic (splat/strategy.py) on the CPU: for each Gaussian, the sum over the
// cameras that see it (radius > 0) of the norm of its 2D mean's gradient in NDC units, and the number of those
// cameras, added in place in one pass. The torch formula it replaces (a nonzero, gathers, a norm, a product, a sum and
// two index_add_ over the rows some camera sees) took 1.6-1.9 ms at 331k Gaussians and 30k seen, this 0.6-0.7 ms
// (two threads, in a loop, 2026-11-26).
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <cmath>

namespace {
#if defined(__x86_64__) && defined(__GNUC__)
__attribute__((target_clones("arch=x86-64-v3", "default")))  // the fused multiply-add in hardware where there is one
#endif
void accumulate(float* __restrict grad_sum, float* __restrict count, const float* __restrict g,
                const int32_t* __restrict radii, int64_t C, int64_t N, float sx, float sy) {
  at::parallel_for(0, N, 16384, [=](int64_t b, int64_t e) {  // by value: the pointers and sizes stay in registers
    for (int64_t n = b; n < e; ++n) {
      float sum = 0.f;
      int32_t seen = 0;
      for (int64_t c = 0; c < C; ++c) {
        const int64_t cn = c * N + n;
        if (radii[cn] <= 0) continue;
        const float x = g[cn * 2] * sx, y = g[cn * 2 + 1] * sy;
        sum += std::sqrt(std::fma(y, y, x * x));  // as torch's vector norm rounds it: fma(y, y, x x)
        ++seen;
      }
      if (seen) {
        grad_sum[n] += sum;
        count[n] += (float)seen;
      }
    }
  });
}
}  // namespace

// grad_sum [N], count [N] float32 (updated in place); g_m2d [C, N, 2] float32, radii [C, N] int32; (sx, sy) = (W / 2,
// H / 2), the NDC scale of the gradient.
void accumulate_screen_grads(torch::Tensor grad_sum, torch::Tensor count, torch::Tensor g_m2d, torch::Tensor radii,
                             double sx, double sy) {
  const int64_t C = g_m2d.size(0), N = g_m2d.size(1);
  TORCH_CHECK(grad_sum.is_contiguous() && count.is_contiguous() && g_m2d.is_contiguous() && radii.is_contiguous(),
              "accumulate_screen_grads: contiguous tensors expected");
  TORCH_CHECK(grad_sum.numel() == N && count.numel() == N && radii.numel() == C * N && g_m2d.size(2) == 2,
              "accumulate_screen_grads: grad_sum, count [N], g_m2d [C, N, 2] and radii [C, N] expected");
  accumulate(grad_sum.data_ptr<float>(), count.data_ptr<float>(), g_m2d.data_ptr<float>(), radii.data_ptr<int32_t>(),
             C, N, (float)sx, (float)sy);
}
