// Work sharing for the cpu backend's loops over Gaussians.
#pragma once
#include <ATen/Parallel.h>
#include <algorithm>
#include <cstdint>

// Calls fn(b, e) for the chunks [b, e) of [0, n), `chunk` long, dealt round-robin to the intra-op threads (thread k
// takes chunks k, k + T, k + 2T, ...). at::parallel_for hands each thread one contiguous range, but the Gaussians a
// view keeps are clustered by index (the initial cloud follows the panorama's pixels, clones are appended), so one
// thread got most of the kept ones and the other waited (the projection's backward, the target command's trained
// model, two threads: 3.18 -> 2.85 ms). fn must not depend on which thread calls it.
template <typename Fn>
void parallel_dealt(int64_t n, int64_t chunk, const Fn& fn) {
  const int64_t chunks = (n + chunk - 1) / chunk;
  const int64_t T = std::max<int64_t>(1, std::min<int64_t>(at::get_num_threads(), chunks));
  at::parallel_for(0, T, 1, [&](int64_t b, int64_t e) {
    for (int64_t th = b; th < e; ++th)
      for (int64_t k = th; k < chunks; k += T) fn(k * chunk, std::min(n, (k + 1) * chunk));
  });
}
