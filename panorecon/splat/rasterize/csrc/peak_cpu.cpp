// The machine's measured limits for the roofline of `panorecon bench` (bench/roofline.py), on every
// thread of ATen's pool: an FMA loop (peak float32 arithmetic) and a STREAM-like copy (memory bandwidth).
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <chrono>
#include <cstring>
#include <vector>

namespace {
typedef float v8f __attribute__((vector_size(32)));
#if defined(__x86_64__) && defined(__GNUC__)
#define PR_PEAK_CLONES __attribute__((target_clones("arch=x86-64-v3", "default")))  // AVX2 + FMA where present
#else
#define PR_PEAK_CLONES
#endif
constexpr int ACC = 12;  // independent accumulators: enough to cover FMA latency x issue width (4 cycles x 2)

// iters x ACC fused multiply-adds on 8 lanes; the result keeps the loop from being optimised away.
PR_PEAK_CLONES __attribute__((noinline)) float fma_loop(int64_t iters, float seed) {
  v8f acc[ACC];
  const v8f zero = {}, m = zero + 0.9999999f, a = zero + 1e-7f;
  for (int i = 0; i < ACC; ++i) acc[i] = zero + seed * (float)(i + 1);
  for (int64_t k = 0; k < iters; ++k)
#pragma GCC unroll 12
    for (int i = 0; i < ACC; ++i) acc[i] = acc[i] * m + a;  // contracted to one FMA where the target has it
  v8f s = zero;
  for (int i = 0; i < ACC; ++i) s += acc[i];
  return s[0] + s[7];
}

#if defined(__x86_64__) && defined(__GNUC__)
// The same loop on 16 lanes (one AVX-512 register per accumulator), for CPUs that have AVX-512F: the peak that
// 16-lane code could reach, where the compositor's 8-lane vectors reach at most the 8-lane loop's.
typedef float v16f __attribute__((vector_size(64)));
__attribute__((target("arch=x86-64-v4"), noinline)) float fma_loop16(int64_t iters, float seed) {
  v16f acc[ACC];
  const v16f zero = {}, m = zero + 0.9999999f, a = zero + 1e-7f;
  for (int i = 0; i < ACC; ++i) acc[i] = zero + seed * (float)(i + 1);
  for (int64_t k = 0; k < iters; ++k)
#pragma GCC unroll 12
    for (int i = 0; i < ACC; ++i) acc[i] = acc[i] * m + a;
  v16f s = zero;
  for (int i = 0; i < ACC; ++i) s += acc[i];
  return s[0] + s[15];
}
bool has_avx512() { return __builtin_cpu_supports("avx512f"); }
#else
float fma_loop16(int64_t, float) { return 0.f; }
bool has_avx512() { return false; }
#endif
}  // namespace

// -> [seconds, flops]: every thread of the pool runs `iters` iterations of the FMA loop (ACC x lanes x 2 flops) on
// `lanes` = 8 (AVX2 + FMA where present) or 16 (AVX-512; [0, 0] on a CPU without it).
std::vector<double> peak_fma(int64_t iters, int64_t lanes) {
  TORCH_CHECK(lanes == 8 || lanes == 16, "peak_fma: lanes must be 8 or 16, got ", lanes);
  if (lanes == 16 && !has_avx512()) return {0.0, 0.0};
  const int64_t threads = at::get_num_threads();
  std::vector<float> sink(threads, 0.f);
  const auto t0 = std::chrono::steady_clock::now();
  at::parallel_for(0, threads, 1, [&](int64_t b, int64_t e) {
    for (int64_t k = b; k < e; ++k)
      sink[k] = lanes == 16 ? fma_loop16(iters, 1e-3f * (float)(k + 1)) : fma_loop(iters, 1e-3f * (float)(k + 1));
  });
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  volatile float keep = 0.f;
  for (float v : sink) keep = keep + v;
  (void)keep;
  return {s, (double)threads * (double)iters * ACC * lanes * 2};
}

// -> [seconds, bytes]: `repeats` copies of a float32 array of `n` elements into another, split across the pool's
// threads (STREAM's Copy; bytes counted as STREAM does, read + write = 8 per element).
std::vector<double> stream_copy(int64_t n, int64_t repeats) {
  std::vector<float> a(n, 1.f), b(n, 0.f);  // touched once before the clock starts
  const auto t0 = std::chrono::steady_clock::now();
  for (int64_t r = 0; r < repeats; ++r)
    at::parallel_for(0, n, 1 << 16, [&](int64_t lo, int64_t hi) {
      std::memcpy(b.data() + lo, a.data() + lo, (hi - lo) * sizeof(float));
    });
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  volatile float keep = b[n / 2];
  (void)keep;
  return {s, 8.0 * (double)n * (double)repeats};
}
