// Tiled Gaussian compositing on the CPU: forward and hand-written backward, parallel over tiles.
// Same rules as the PyTorch reference (torch_backend.py): pixel centres at +0.5; alpha = min(0.999, o exp(-sigma));
// alpha < 1/255 or sigma < 0 skipped; stop before the Gaussian that would take T to <= 1e-4.
// Layout of the work: the visible pairs are sorted by depth once (radix sort), then binned to 16x16 tiles in that
// order (counting sort), so each tile's list is front to back; a tile's Gaussians are gathered into contiguous
// arrays; each 4x4 block of pixels gets the sub-list of those that may reach alpha >= 1/255 at one of its pixel
// centres (built by the forward, kept for the backward), and its 16 pixels are composited in lockstep as two
// 8-float vectors.
// Float32 throughout. Gradients are summed per tile, then into one buffer per thread, then across threads.
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>
#include <vector>

namespace {
constexpr float ALPHA_MIN = 1.0f / 255.0f;
constexpr float ALPHA_MAX = 0.999f;  // gsplat's cap (the original 3DGS kernels use 0.99)
constexpr float T_MIN = 1e-4f;

struct Bins {
  std::vector<int64_t> offsets;  // [C * tiles + 1]
  std::vector<int32_t> ids;      // Gaussian ids, per tile front to back
};

// floor(x) for finite |x| < 2^62, inline: std::floor is a libm call in the baseline (SSE2) build, and binning called
// it four times per visible pair and sweep.
inline int64_t floor_i64(float x) {
  const int64_t i = (int64_t)x;  // truncates towards 0
  return x < (float)i ? i - 1 : i;
}

// Calls fn(tile index within camera c) for every tile the Gaussian's square [m - r, m + r] touches
// (the reference's test: the square overlaps [t, t + size] on both axes).
template <typename Fn>
inline void for_each_tile(float mx, float my, int32_t r, int64_t W, int64_t H, int64_t tile, Fn fn) {
  const int64_t tx_n = (W + tile - 1) / tile, ty_n = (H + tile - 1) / tile;
  const int64_t x0 = std::max<int64_t>(0, floor_i64((mx - r) / tile));
  const int64_t x1 = std::min<int64_t>(tx_n - 1, floor_i64((mx + r) / tile));
  const int64_t y0 = std::max<int64_t>(0, floor_i64((my - r) / tile));
  const int64_t y1 = std::min<int64_t>(ty_n - 1, floor_i64((my + r) / tile));
  for (int64_t ty = y0; ty <= y1; ++ty)
    for (int64_t tx = x0; tx <= x1; ++tx) {
      const float left = tx * tile, right = std::min<int64_t>(W, (tx + 1) * tile);
      const float top = ty * tile, bottom = std::min<int64_t>(H, (ty + 1) * tile);
      if (mx + r >= left && mx - r <= right && my + r >= top && my - r <= bottom) fn(ty * tx_n + tx);
    }
}

// A uint32 that orders as the float does (IEEE 754 bits, negatives flipped), -0 and +0 alike (a NaN depth, which the
// projection culls, has no place in the order).
inline uint32_t depth_key(float z) {
  uint32_t u;
  z += 0.f;  // -0 -> +0
  std::memcpy(&u, &z, sizeof u);
  return (u & 0x80000000u) ? ~u : u | 0x80000000u;
}

// The row of each (camera, Gaussian) pair among the visible pairs (radius > 0), in index order; -1 where culled. The
// compositor's per-thread buffers hold the visible pairs only (a fraction of C N in a narrow view, so the buffers
// zeroed and reduced every call shrink with it). V: the number of visible pairs. Counted per chunk in parallel, then
// numbered from each chunk's start.
std::vector<int32_t> visible_slots(const int32_t* radii, int64_t CN, int32_t& V) {
  TORCH_CHECK(CN < INT32_MAX, "compositing: ", CN, " (camera, Gaussian) pairs; at most 2^31 - 1");
  std::vector<int32_t> slot(CN);
  const int64_t chunks = std::max<int64_t>(1, std::min<int64_t>(64, CN / 16384)), len = (CN + chunks - 1) / chunks;
  std::vector<int32_t> start(chunks + 1, 0);
  at::parallel_for(0, chunks, 1, [&](int64_t b, int64_t e) {
    for (int64_t k = b; k < e; ++k) {
      int32_t count = 0;  // a local: start's int32 stores may alias radii, and kept the loop scalar
      for (int64_t cn = k * len; cn < std::min(CN, (k + 1) * len); ++cn) count += radii[cn] > 0;
      start[k + 1] = count;
    }
  });
  for (int64_t k = 0; k < chunks; ++k) start[k + 1] += start[k];
  at::parallel_for(0, chunks, 1, [&](int64_t b, int64_t e) {
    for (int64_t k = b; k < e; ++k) {
      int32_t v = start[k];
      int32_t* __restrict out = slot.data();
      for (int64_t cn = k * len, end = std::min(CN, (k + 1) * len); cn < end; ++cn) out[cn] = radii[cn] > 0 ? v++ : -1;
    }
  });
  V = start[chunks];
  return slot;
}

// A visible pair (radius > 0): its camera c, Gaussian n and what binning reads of it, copied out in index order so
// that the sweeps in depth order read a few hundred kilobytes instead of gathering from [C, N] arrays (a cache miss
// per pair: 30 % of binning's time, perf). c and n are kept apart: the sweeps divided c N + n by N twice per pair.
struct VisiblePair {
  int32_t c, n;
  float mx, my;
  int32_t r;
};

// The visible pairs, camera by camera, each camera's sorted by depth with ties in id order (the reference's stable
// argsort): a stable least-significant-digit radix sort of the pairs in index order by depth_key, 8 bits a pass, a
// pass skipped where every key shares its byte (depths of one scene share their top bits). Each pass runs in
// parallel over fixed chunks of the camera's pairs: every chunk counts its digits, a prefix sum over (digit, chunk)
// gives each chunk its write positions, and the chunks scatter in their order, so the result is the serial sort's
// whatever the thread count (the serial passes left the other thread waiting: ~3 % of the compositing, perf).
std::vector<VisiblePair> visible_by_depth(const float* m2d, const float* depth, const int32_t* radii, int64_t C,
                                          int64_t N, const std::vector<int32_t>& slot, int32_t V) {
  std::vector<VisiblePair> pairs(V), tmp(V);
  std::vector<uint32_t> key(V), key_tmp(V);
  for (int64_t c = 0; c < C; ++c)
    at::parallel_for(0, N, 16384, [&](int64_t b, int64_t e) {
      for (int64_t n = b; n < e; ++n) {
        const int64_t cn = c * N + n;
        if (slot[cn] < 0) continue;
        pairs[slot[cn]] = {(int32_t)c, (int32_t)n, m2d[cn * 2], m2d[cn * 2 + 1], radii[cn]};
        key[slot[cn]] = depth_key(depth[cn]);
      }
    });
  constexpr int64_t DIGITS = 256;
  std::vector<int64_t> pos;  // per (chunk, digit): counts, then write positions
  int64_t first = 0;
  while (first < V) {  // one camera's run [first, last)
    const int32_t c = pairs[first].c;
    int64_t last = first;
    while (last < V && pairs[last].c == c) ++last;
    const int64_t n = last - first, chunks = std::max<int64_t>(1, std::min<int64_t>(64, n / 4096));
    const int64_t len = (n + chunks - 1) / chunks;
    for (int shift = 0; shift < 32; shift += 8) {
      pos.assign(chunks * DIGITS, 0);
      at::parallel_for(0, chunks, 1, [&](int64_t b, int64_t e) {
        for (int64_t k = b; k < e; ++k) {
          int64_t* p = pos.data() + k * DIGITS;
          for (int64_t i = first + k * len, end = std::min(last, first + (k + 1) * len); i < end; ++i)
            ++p[(key[i] >> shift) & 255];
        }
      });
      int64_t run = first;
      bool one_bucket = false;
      for (int64_t d = 0; d < DIGITS; ++d) {
        const int64_t start = run;
        for (int64_t k = 0; k < chunks; ++k) {
          const int64_t count = pos[k * DIGITS + d];
          pos[k * DIGITS + d] = run;
          run += count;
        }
        one_bucket |= run - start == n;
      }
      if (one_bucket) continue;  // every key shares this byte: the order is unchanged
      at::parallel_for(0, chunks, 1, [&](int64_t b, int64_t e) {
        for (int64_t k = b; k < e; ++k) {
          int64_t* p = pos.data() + k * DIGITS;
          for (int64_t i = first + k * len, end = std::min(last, first + (k + 1) * len); i < end; ++i) {
            const int64_t to = p[(key[i] >> shift) & 255]++;
            tmp[to] = pairs[i];
            key_tmp[to] = key[i];
          }
        }
      });
      at::parallel_for(first, last, 8192, [&](int64_t b, int64_t e) {
        std::copy(tmp.begin() + b, tmp.begin() + e, pairs.begin() + b);
        std::copy(key_tmp.begin() + b, key_tmp.begin() + e, key.begin() + b);
      });
    }
    first = last;
  }
  return pairs;
}

// Counting sort of (camera, tile) hits in parallel over the visible pairs in depth order: the pairs are cut into
// fixed chunks, each chunk counts its hits per tile, a prefix sum over (tile, chunk) gives every chunk its write
// position, and a second pass writes the ids, which so come out front to back within each tile, ties in id order,
// whatever the thread count. This replaced a std::sort per tile of the ids by depth.
Bins bin(const float* m2d, const float* depth, const int32_t* radii, int64_t C, int64_t N, int64_t W, int64_t H,
         int64_t tile, const std::vector<int32_t>& slot, int32_t n_visible) {
  const int64_t tiles = ((W + tile - 1) / tile) * ((H + tile - 1) / tile), CT = C * tiles;
  const std::vector<VisiblePair> pairs = visible_by_depth(m2d, depth, radii, C, N, slot, n_visible);
  const int64_t V = (int64_t)pairs.size();
  const int64_t chunks = std::max<int64_t>(1, std::min<int64_t>(64, V / 512)), len = (V + chunks - 1) / chunks;
  std::vector<int64_t> pos(chunks * CT, 0);  // counts, then write positions, per (chunk, tile)
  auto sweep = [&](bool write, int32_t* ids) {
    at::parallel_for(0, chunks, 1, [&](int64_t b, int64_t e) {
      for (int64_t k = b; k < e; ++k) {
        int64_t* p = pos.data() + k * CT;
        for (int64_t v = k * len; v < std::min(V, (k + 1) * len); ++v) {
          const VisiblePair& q = pairs[v];
          const int64_t base = q.c * tiles;
          const int32_t id = q.n;
          for_each_tile(q.mx, q.my, q.r, W, H, tile, [&](int64_t t) {
            if (write) ids[p[base + t]++] = id;
            else ++p[base + t];
          });
        }
      }
    });
  };
  sweep(false, nullptr);
  Bins out;
  out.offsets.assign(CT + 1, 0);
  int64_t run = 0;
  for (int64_t t = 0; t < CT; ++t) {
    out.offsets[t] = run;
    for (int64_t k = 0; k < chunks; ++k) {
      const int64_t count = pos[k * CT + t];
      pos[k * CT + t] = run;
      run += count;
    }
  }
  out.offsets[CT] = run;
  out.ids.resize(run);
  sweep(true, out.ids.data());
  return out;
}

// Per (camera, Gaussian) pair, the bounds beyond which its alpha is surely below 1/255: o exp(-sigma) < 1/255 once
// sigma > ln(255 o) (sigma_cut), and since sigma >= 0.5 lambda_min(conic) |d|^2, once the squared pixel distance
// |d|^2 > 2 ln(255 o) / lambda_min (disc). disc -1: never visible. Kept for the visible pairs only, at their slot
// (a culled pair, radius <= 0, is in no tile's list: neither a logarithm nor a store is spent on it, and the culled
// ~90 % of a narrow view's [C, N] pairs are skipped without the index arithmetic). Both carry margins that keep the tests conservative under float
// rounding; sigma's rounding error grows with its terms, up to lambda_max |d|^2, hence the condition number in the
// margin of sigma_cut.
struct Cutoffs {
  std::vector<float> disc, sigma;
};
Cutoffs cutoffs(const float* con, const float* op, const int32_t* radii, int64_t C, int64_t N,
                const std::vector<int32_t>& slot, int32_t V) {
  Cutoffs cut{std::vector<float>(V), std::vector<float>(V)};  // per visible pair, at its slot
  for (int64_t c = 0; c < C; ++c)
    at::parallel_for(0, N, 4096, [&](int64_t b, int64_t e) {
      for (int64_t n = b; n < e; ++n) {
        const int64_t cn = c * N + n;
        if (radii[cn] <= 0) continue;
        const float o = op[n];
        float& disc = cut.disc[slot[cn]];
        float& sigma = cut.sigma[slot[cn]];
        if (o * 255.f <= 1.f) { disc = sigma = -1.f; continue; }
        const float a = con[cn * 3], bb = con[cn * 3 + 1], cc = con[cn * 3 + 2];
        const float mid = 0.5f * (a + cc), det = a * cc - bb * bb, root = std::sqrt(std::max(mid * mid - det, 0.f));
        const float lmin = mid - root, lmax = mid + root, level = std::log(o * 255.f);
        disc = lmin > 0.f ? 2.f * level / lmin * 1.001f + 1e-3f : INFINITY;
        sigma = lmin > 0.f ? level * (1.001f + 1e-5f * (lmax / lmin)) + 1e-3f : INFINITY;
      }
    });
  return cut;
}

// n_buf buffers of len zeros, one after another, each zeroed by a thread: a std::vector's serial memset of the
// backward's buffers took ~2 % of the compositing's time while the other thread waited (perf).
std::unique_ptr<float[]> zeroed_buffers(int64_t n_buf, int64_t len) {
  std::unique_ptr<float[]> buf(new float[std::max<int64_t>(1, n_buf * len)]);  // uninitialised
  at::parallel_for(0, n_buf, 1, [&](int64_t b, int64_t e) { std::fill(buf.get() + b * len, buf.get() + e * len, 0.f); });
  return buf;
}

constexpr int64_t BLOCK = 4;  // pixels per side of the sub-tile blocks that pre-filter a tile's list
inline int64_t blocks_per_tile(int64_t tile) { return ((tile + BLOCK - 1) / BLOCK) * ((tile + BLOCK - 1) / BLOCK); }

// The kernel's read-only inputs, [C, N, ...] contiguous float32; the cutoffs per visible pair, at slot[c N + n].
struct Inputs {
  const float *m2d, *con, *col, *op, *dz, *disc, *sigma_cut;
  const int32_t* slot;
  int64_t N;
};

// One tile's Gaussians, front to back, copied into contiguous arrays so that the per-pixel loops stream through
// a few kilobytes instead of gathering from the [C, N] inputs.
struct TileGaussians {
  std::vector<int32_t> id;
  std::vector<float> mx, my, disc, sigma_cut, qa, qb, qc, op, r, g, b, z;
  void gather(const int32_t* ids, int64_t n, int64_t c, const Inputs& in) {  // cutoffs too unless in.disc is null
    for (auto* v : {&mx, &my, &qa, &qb, &qc, &op, &r, &g, &b, &z}) v->resize(n);
    id.assign(ids, ids + n);
    if (in.disc) {
      disc.resize(n); sigma_cut.resize(n);
      for (int64_t k = 0; k < n; ++k) {
        const int32_t v = in.slot[c * in.N + ids[k]];
        disc[k] = in.disc[v]; sigma_cut[k] = in.sigma_cut[v];
      }
    }
    for (int64_t k = 0; k < n; ++k) {
      const int64_t cn = c * in.N + ids[k];
      mx[k] = in.m2d[cn * 2]; my[k] = in.m2d[cn * 2 + 1];
      qa[k] = in.con[cn * 3]; qb[k] = in.con[cn * 3 + 1]; qc[k] = in.con[cn * 3 + 2];
      op[k] = in.op[ids[k]];
      r[k] = in.col[cn * 3]; g[k] = in.col[cn * 3 + 1]; b[k] = in.col[cn * 3 + 2]; z[k] = in.dz[cn];
    }
  }
};

// Calls fn(i0, i1, j0, j1) for the BLOCK x BLOCK pixel blocks [i0, i1) x [j0, j1) of tile t of a camera, row by row.
template <typename Fn>
inline void for_each_block(int64_t t, int64_t W, int64_t H, int64_t tile, Fn fn) {
  const int64_t tx_n = (W + tile - 1) / tile, ty = t / tx_n, tx = t % tx_n;
  for (int64_t i0 = ty * tile; i0 < std::min<int64_t>(H, (ty + 1) * tile); i0 += BLOCK)
    for (int64_t j0 = tx * tile; j0 < std::min<int64_t>(W, (tx + 1) * tile); j0 += BLOCK)
      fn(i0, std::min<int64_t>({H, (ty + 1) * tile, i0 + BLOCK}), j0, std::min<int64_t>({W, (tx + 1) * tile, j0 + BLOCK}));
}

// The pixels of a BLOCK x BLOCK block are composited in lockstep as VECS vectors of 8 floats (GCC/Clang vector
// extensions: AVX2 registers with fused multiply-adds in the x86-64-v3 clone, pairs of SSE registers in the default
// one). The x86-64-v4 clone (AVX-512) runs the same 8-lane vectors with 32 registers instead of 16: the backward's
// live state (the lanes' centres, T, the four suffix sums and the ten gradient accumulators) no longer spills, and
// on the target command's trained model both passes are ~10 % faster with bit-identical outputs (docs/benchmarks.md).
typedef float v8f __attribute__((vector_size(32)));
typedef int32_t v8i __attribute__((vector_size(32)));
constexpr int LANES = BLOCK * BLOCK, VECS = LANES / 8;
static_assert(LANES % 8 == 0, "a block must fill whole vectors");

#define PR_INLINE inline __attribute__((always_inline))
#if defined(__x86_64__) && defined(__GNUC__)
#define PR_CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))  // the loader picks
#else
#define PR_CLONES
#endif
PR_INLINE v8f select(v8i mask, v8f a, v8f b) { return mask ? a : b; }
template <class V> PR_INLINE V vmin(V a, V b) { return a < b ? a : b; }
template <class V> PR_INLINE V vmax(V a, V b) { return a > b ? a : b; }
// Horizontal reductions by halving shuffles (two 128-bit halves, then lanes): indexing the eight lanes one by one
// compiled to a chain of eight lane extracts, and the backward's ten sums per list entry were ~10 % of its time.
typedef float v4f __attribute__((vector_size(16)));
typedef int32_t v4i __attribute__((vector_size(16)));
typedef int64_t v2l __attribute__((vector_size(16)));
PR_INLINE v4f lo4(v8f v) { return __builtin_shufflevector(v, v, 0, 1, 2, 3); }
PR_INLINE v4f hi4(v8f v) { return __builtin_shufflevector(v, v, 4, 5, 6, 7); }
PR_INLINE float hsum(v8f v) {
  const v4f h = lo4(v) + hi4(v);
  return (h[0] + h[2]) + (h[1] + h[3]);
}
PR_INLINE float hmax(v8f v) {
  const v4f h = vmax(lo4(v), hi4(v));
  return std::max(std::max(h[0], h[2]), std::max(h[1], h[3]));
}
PR_INLINE bool any_set(v8i m) {
  const v2l h = (v2l)(__builtin_shufflevector(m, m, 0, 1, 2, 3) | __builtin_shufflevector(m, m, 4, 5, 6, 7));
  return (h[0] | h[1]) != 0;
}
// The lane sums of eight vectors in one vector, s[i] = hsum(a[i]), by a transpose-and-add tree: 7 adds and 14
// shuffles where eight hsum calls take 8 x (3 adds + 3 shuffles / extracts).
PR_INLINE v8f hsum8(const v8f* a) {
  v8f t[4], u[2];
  for (int i = 0; i < 4; ++i)  // lanes alternate a[2i], a[2i+1]: pairs summed
    t[i] = __builtin_shufflevector(a[2 * i], a[2 * i + 1], 0, 8, 2, 10, 4, 12, 6, 14) +
           __builtin_shufflevector(a[2 * i], a[2 * i + 1], 1, 9, 3, 11, 5, 13, 7, 15);
  for (int i = 0; i < 2; ++i)  // lanes a[4i .. 4i+3], twice: quads summed
    u[i] = __builtin_shufflevector(t[2 * i], t[2 * i + 1], 0, 1, 8, 9, 4, 5, 12, 13) +
           __builtin_shufflevector(t[2 * i], t[2 * i + 1], 2, 3, 10, 11, 6, 7, 14, 15);
  return __builtin_shufflevector(u[0], u[1], 0, 1, 2, 3, 8, 9, 10, 11) +
         __builtin_shufflevector(u[0], u[1], 4, 5, 6, 7, 12, 13, 14, 15);
}

// Every block's list of a tile (the blocks in for_each_block's order): the positions, front to back, of the tile's
// Gaussians that may reach alpha >= 1/255 at one of the block's pixel centres: the smallest sigma over the rectangle
// of centres is <= sigma_cut, and the cutoff disc reaches it (a NaN excludes). The disc alone kept entries that no
// lane composited, elongated Gaussians whose disc is much wider than their ellipse: with the sigma test a pixel of
// the target command's trained model goes through 19 % fewer list entries (eval/compositor_builds.py --run,
// mean_list_end 125.4 -> 101.9). Built in one pass over the tile's Gaussians, each tested against all the tile's blocks at once, 8 blocks to
// a vector, without a branch: the scalar scan per block that it replaces took about a quarter of the compositing's
// time at 256^2 / 100k (perf). The forward builds them and hands them to the backward (block_start, block_pos),
// which walked the same lists after building them again.
struct BlockLists {
  int64_t n_blocks = 0, cap = 0;
  std::vector<float> x0, x1, y0, y1;  // pixel-centre rectangle of each block, padded to 8 (+inf: never read)
  std::vector<int32_t> count, pos;  // pos: cap entries per block
  const int32_t* list(int64_t b) const { return pos.data() + b * cap; }
};

PR_CLONES
void build_block_lists(BlockLists& L, const TileGaussians& G, int64_t t, int64_t W, int64_t H, int64_t tile) {
  std::vector<float> r0, r1, c0, c1;
  for_each_block(t, W, H, tile, [&](int64_t i0, int64_t i1, int64_t j0, int64_t j1) {
    c0.push_back(j0 + 0.5f); c1.push_back(j1 - 0.5f); r0.push_back(i0 + 0.5f); r1.push_back(i1 - 0.5f);
  });
  L.n_blocks = (int64_t)c0.size();
  const int64_t nv = (L.n_blocks + 7) / 8;
  for (auto* v : {&c0, &c1, &r0, &r1}) v->resize(nv * 8, INFINITY);
  L.x0 = c0; L.x1 = c1; L.y0 = r0; L.y1 = r1;
  L.cap = (int64_t)G.id.size();
  L.count.assign(nv * 8, 0);
  L.pos.resize(nv * 8 * L.cap);
  const v8f zero = {};
  for (int64_t k = 0; k < L.cap; ++k) {
    const float mx = G.mx[k], my = G.my[k], disc = G.disc[k], s_cut = G.sigma_cut[k];
    const float a = G.qa[k], b = G.qb[k], c = G.qc[k], b_a = b / a, b_c = b / c;
    // sigma(u, v) = 0.5 (a u^2 + c v^2) + b u v at offset (u, v) from the mean; on an edge u = const its minimum is
    // at v = -b u / c (clamped to the edge), on v = const at u = -b v / a
    auto sigma = [&](v8f u, v8f v) { return u * (0.5f * a * u + b * v) + 0.5f * c * v * v; };
    for (int64_t v = 0; v < nv; ++v) {
      v8f x0, x1, y0, y1;  // unaligned loads: a std::vector is not 32-byte aligned
      std::memcpy(&x0, &L.x0[v * 8], sizeof(v8f)); std::memcpy(&x1, &L.x1[v * 8], sizeof(v8f));
      std::memcpy(&y0, &L.y0[v * 8], sizeof(v8f)); std::memcpy(&y1, &L.y1[v * 8], sizeof(v8f));
      const v8f dx = vmax(zero, vmax(x0 - mx, mx - x1)), dy = vmax(zero, vmax(y0 - my, my - y1));
      const v8f u0 = x0 - mx, u1 = x1 - mx, v0 = y0 - my, v1 = y1 - my;
      const v8f s_edges = vmin(vmin(sigma(u0, vmin(vmax(-b_c * u0, v0), v1)), sigma(u1, vmin(vmax(-b_c * u1, v0), v1))),
                               vmin(sigma(vmin(vmax(-b_a * v0, u0), u1), v0), sigma(vmin(vmax(-b_a * v1, u0), u1), v1)));
      const v8i inside = (dx == zero) & (dy == zero);  // the mean lies in the rectangle: sigma's minimum is 0
      const v8i in = (dx * dx + dy * dy <= disc) & (inside | ~(s_edges > s_cut));  // a NaN sigma keeps it
      for (int u = 0; u < 8; ++u) {  // append k where reached: store always, advance the count by the mask
        const int64_t b = v * 8 + u;
        L.pos[b * L.cap + L.count[b]] = (int32_t)k;
        L.count[b] += in[u] & 1;
      }
    }
  }
}

// exp(-s) per lane for s >= 0: Cephes' expf (range reduction by ln 2 in two parts, degree-6 polynomial,
// exponent bits); relative error below 2e-7. s is clamped to [0, 40]: exp(-40) is far below any alpha that counts
// (1/255), and the clamp keeps o * exp(-s) out of the denormals, which cost ~100x.
PR_INLINE v8f exp_neg(v8f s) {
  const v8f zero = {}, forty = zero + 40.f;
  s = vmin(vmax(s, zero), forty);
  const v8i n_i = __builtin_convertvector(s * 1.44269504f + 0.5f, v8i);  // round(s / ln 2), s >= 0
  const v8f n = __builtin_convertvector(n_i, v8f);
  const v8f x = (n * 0.693359375f - s) + n * -2.12194440e-4f;  // n ln 2 - s, in [-ln2/2, ln2/2]
  // the polynomial by Estrin's scheme: three independent pairs, then two levels; Horner's chain of six dependent
  // multiply-adds was the longest latency of the backward's per-entry work (perf)
  const v8f x2 = x * x, x4 = x2 * x2;
  const v8f p01 = x * 1.6666665459e-1f + 5.0000001201e-1f, p23 = x * 8.3334519073e-3f + 4.1665795894e-2f,
            p45 = x * 1.9875691500e-4f + 1.3981999507e-3f;
  const v8f y = ((p01 + x2 * p23) + x4 * p45) * x2 + x + 1.f;
  return y * (v8f)((127 - n_i) << 23);  // times 2^-n
}

// Lane p of a block is pixel (i0 + p / BLOCK, j0 + p % BLOCK); pixel centres at +0.5.
PR_INLINE void lane_centres(int64_t i0, int64_t j0, v8f* px, v8f* py) {
  for (int p = 0; p < LANES; ++p) {
    px[p / 8][p % 8] = j0 + p % BLOCK + 0.5f;
    py[p / 8][p % 8] = i0 + p / BLOCK + 0.5f;
  }
}

struct BlockOut {  // per lane: transmittance, rgb, accumulated z, entries of the block list composited
  v8f T[VECS], r[VECS], g[VECS], b[VECS], d[VECS], end[VECS];
};

// Composites one block's list front to back, all lanes at once; a lane stops before the Gaussian that would take
// its T to <= T_MIN, lanes outside the image start stopped. With CONTRIB, adds this block's weight sum, and maxes
// its weight max and max T, into contrib[3 l .. 3 l + 2] for the tile's Gaussian l (the tile's own buffer).
// The list is walked in batches of ENTRY_BATCH entries: first every entry's alpha in every lane (independent of one
// another), then the blend, whose transmittance carries from entry to entry: the exps of a batch no longer wait in
// the core's reorder window behind the blend's chain. Same arithmetic, same bits; on the target command's trained
// model ~1.09x forward and ~1.05x backward (batches of 8, 16 and 32 within the noise of each other; docs/benchmarks.md).
constexpr int64_t ENTRY_BATCH = 32;

// alpha of list entries [k0, k0 + nb) in every lane, A[j] for entry k0 + j: min(0.999, o exp(-sigma)) where
// sigma >= 0 and it is >= 1/255, else 0 (a NaN sigma gives 0); with WITH_VIS also exp(-sigma) itself, in E[j]
template <bool WITH_VIS>
PR_INLINE void batch_alphas(const TileGaussians& G, const int32_t* list, int64_t k0, int64_t nb, const v8f* px,
                            const v8f* py, v8f (*A)[VECS], v8f (*E)[VECS]) {
  const v8f zero = {};
  for (int64_t j = 0; j < nb; ++j) {
    const int64_t l = list[k0 + j];
    const float mx = G.mx[l], my = G.my[l], qa = G.qa[l], qb = G.qb[l], qc = G.qc[l], o = G.op[l];
    for (int v = 0; v < VECS; ++v) {
      const v8f dx = px[v] - mx, dy = py[v] - my;
      const v8f sigma = 0.5f * (qa * dx * dx + qc * dy * dy) + qb * dx * dy;
      const v8f vis = exp_neg(sigma), a = vmin(zero + ALPHA_MAX, o * vis);
      A[j][v] = select((sigma >= 0.f) & (a >= ALPHA_MIN), a, zero);
      if constexpr (WITH_VIS) E[j][v] = vis;
    }
  }
}

template <bool CONTRIB>
PR_CLONES void composite_block(const TileGaussians& G, const int32_t* list, int64_t n_l, int64_t i0, int64_t i1,
                               int64_t j0, int64_t j1, BlockOut& out, float* contrib) {
  v8f px[VECS], py[VECS], T[VECS], r[VECS], g[VECS], b[VECS], d[VECS], end[VECS];
  v8i live[VECS];
  v8f A[ENTRY_BATCH][VECS];
  lane_centres(i0, j0, px, py);
  const v8f zero = {};
  for (int v = 0; v < VECS; ++v) {
    T[v] = zero + 1.f;
    r[v] = g[v] = b[v] = d[v] = end[v] = zero;
    live[v] = (px[v] < (float)j1) & (py[v] < (float)i1);
  }
  bool any_live = true;
  for (int64_t k0 = 0; k0 < n_l && any_live; k0 += ENTRY_BATCH) {
    const int64_t nb = std::min(ENTRY_BATCH, n_l - k0);
    batch_alphas<false>(G, list, k0, nb, px, py, A, nullptr);
    for (int64_t j = 0; j < nb; ++j) {
      const int64_t k = k0 + j, l = list[k];
      const float cr = G.r[l], cg = G.g[l], cb = G.b[l], cz = G.z[l], k1 = (float)(k + 1);
      v8f w_sum = zero, w_max = zero, t_max = zero;
      v8i alive = {};
      // No early `continue` when no lane uses the entry: its test was a mispredicted branch (perf), dearer than the
      // masked updates below, which then change nothing.
      for (int v = 0; v < VECS; ++v) {
        const v8f a = A[j][v];
        const v8i use = live[v] & (a >= ALPHA_MIN);
        const v8f nextT = T[v] * (1.f - a);
        const v8i stop = use & (nextT <= T_MIN);
        const v8i add = use & ~stop;
        const v8f w = select(add, a * T[v], zero);
        t_max = vmax(t_max, select(add, T[v], zero));
        r[v] += w * cr; g[v] += w * cg; b[v] += w * cb; d[v] += w * cz;
        T[v] = select(add, nextT, T[v]);
        end[v] = select(add, zero + k1, end[v]);
        live[v] &= ~stop;
        alive |= live[v];
        w_sum += w;
        w_max = vmax(w_max, w);
      }
      if constexpr (CONTRIB) {  // all three are 0 where no lane composited it: adding or maxing changes nothing
        float* q = contrib + 3 * l;
        q[0] += hsum(w_sum);
        q[1] = std::max(q[1], hmax(w_max));
        q[2] = std::max(q[2], hmax(t_max));
      }
      if (!any_set(alive)) { any_live = false; break; }
    }
  }
  for (int v = 0; v < VECS; ++v) {
    out.T[v] = T[v]; out.r[v] = r[v]; out.g[v] = g[v]; out.b[v] = b[v]; out.d[v] = d[v]; out.end[v] = end[v];
  }
}

struct BlockGrad {  // per lane: dL/d(rgb, z, alpha) of the pixel, its final T and list end (0 outside the image)
  v8f gr[VECS], gg[VECS], gb[VECS], gz[VECS], ga[VECS], T_end[VECS], end[VECS];
};

// The backward of composite_block: walks the block's list back to front from the largest end (a lane joins once
// k < its end), recovering the transmittance in front of each Gaussian as T / (1 - alpha), and adds the block's
// gradients to grad (10 per tile Gaussian: means2d x y, conic a b c, rgb, z, opacity). In batches of ENTRY_BATCH
// entries, as the forward: the alphas and exp(-sigma) of a batch first, then its entries back to front.
PR_CLONES
void composite_block_backward(const TileGaussians& G, const int32_t* list, int64_t i0, int64_t j0,
                              const BlockGrad& in, float* grad) {
  v8f px[VECS], py[VECS], T[VECS], Sr[VECS], Sg[VECS], Sb[VECS], Sd[VECS];
  v8f A[ENTRY_BATCH][VECS], E[ENTRY_BATCH][VECS];
  lane_centres(i0, j0, px, py);
  const v8f zero = {};
  float k_max = 0.f;
  for (int v = 0; v < VECS; ++v) {
    T[v] = in.T_end[v];
    Sr[v] = Sg[v] = Sb[v] = Sd[v] = zero;
    k_max = std::max(k_max, hmax(in.end[v]));
  }
  for (int64_t k_end = (int64_t)k_max; k_end > 0; k_end -= ENTRY_BATCH) {  // the batch [k_end - nb, k_end)
    const int64_t nb = std::min(ENTRY_BATCH, k_end), k0 = k_end - nb;
    batch_alphas<true>(G, list, k0, nb, px, py, A, E);
    for (int64_t j = nb - 1; j >= 0; --j) {
      const int64_t k = k0 + j, l = list[k];
      const float mx = G.mx[l], my = G.my[l], qa = G.qa[l], qb = G.qb[l], qc = G.qc[l], o = G.op[l];
      const float cr = G.r[l], cg = G.g[l], cb = G.b[l], cz = G.z[l], kf = (float)k;
      v8f g_mx = zero, g_my = zero, g_qa = zero, g_qb = zero, g_qc = zero, g_r = zero, g_g = zero, g_b = zero,
          g_z = zero, g_o = zero;
      // no skip when no lane uses the entry (the masks then add zeros): the skip's branch cost more than the work it
      // saved, as in the forward (two threads, target command's model: backward 12.9 -> 12.6 ms)
      for (int v = 0; v < VECS; ++v) {
        const v8f dx = px[v] - mx, dy = py[v] - my, a = A[j][v], vis = E[j][v];
        const v8i use = (kf < in.end[v]) & (a >= ALPHA_MIN);
        const v8f inv = 1.f / (1.f - a);
        const v8f Tb = T[v] * inv;  // transmittance in front of it
        const v8f w = select(use, a * Tb, zero);
        g_r += w * in.gr[v]; g_g += w * in.gg[v]; g_b += w * in.gb[v]; g_z += w * in.gz[v];
        const v8f g_a = Tb * (cr * in.gr[v] + cg * in.gg[v] + cb * in.gb[v] + cz * in.gz[v])
                        - (Sr[v] * in.gr[v] + Sg[v] * in.gg[v] + Sb[v] * in.gb[v] + Sd[v] * in.gz[v]) * inv
                        + in.ga[v] * in.T_end[v] * inv;
        Sr[v] += w * cr; Sg[v] += w * cg; Sb[v] += w * cb; Sd[v] += w * cz;
        T[v] = select(use, Tb, T[v]);
        // a clamped alpha passes no gradient to opacity or shape
        const v8f g_vis = select(use & (o * vis <= ALPHA_MAX), vis * g_a, zero);
        g_o += g_vis;
        const v8f g_sigma = -o * g_vis;
        g_qa += 0.5f * dx * dx * g_sigma;
        g_qb += dx * dy * g_sigma;
        g_qc += 0.5f * dy * dy * g_sigma;
        // qa dx, qb dx and qc dy rounded on their own before the sums (the barriers keep GCC from fusing them into
        // multiply-adds), as when one loop shared them with sigma: the gradients of the one-pass kernel, to the bit
        g_mx -= (__builtin_assoc_barrier(qa * dx) + qb * dy) * g_sigma;
        g_my -= (__builtin_assoc_barrier(qb * dx) + __builtin_assoc_barrier(qc * dy)) * g_sigma;
      }
      float* q = grad + l * 10;  // q[0..7] += the first eight sums as one vector (unaligned), then z and opacity
      const v8f first8[8] = {g_mx, g_my, g_qa, g_qb, g_qc, g_r, g_g, g_b};
      v8f sums;
      std::memcpy(&sums, q, sizeof(v8f));
      sums += hsum8(first8);
      std::memcpy(q, &sums, sizeof(v8f));
      q[8] += hsum(g_z); q[9] += hsum(g_o);
    }
  }
}

}  // namespace

// -> image [C,H,W,3], alpha [C,H,W,1], depth [C,H,W,1], T_final [C,H,W], last [C,H,W] (int32: how many
// entries of the pixel's 4x4-block list were composited), offsets, ids (the tiles' depth-sorted Gaussians),
// block_start [C * tiles * blocks_per_tile + 1] and block_pos (int32: each block's list, as positions in its tile's
// ids; a tile's blocks in for_each_block's order, then empty ones), and with want_contrib the per-Gaussian
// weight_sum, weight_max (sum / max over pixels of alpha*T) and trans_max (max T in front of it where it was
// composited) [C,N]; else three empty tensors. Contributions are summed per tile, then into one buffer of 3 floats
// per visible pair and thread, then across threads.
std::vector<torch::Tensor> forward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor colors,
                                   torch::Tensor opacities, torch::Tensor depths, torch::Tensor radii, int64_t W,
                                   int64_t H, int64_t tile, bool want_contrib) {
  const int64_t C = means2d.size(0), N = means2d.size(1);
  int32_t V = 0;
  const std::vector<int32_t> slot = visible_slots(radii.data_ptr<int32_t>(), C * N, V);
  const Bins bins =
      bin(means2d.data_ptr<float>(), depths.data_ptr<float>(), radii.data_ptr<int32_t>(), C, N, W, H, tile, slot, V);
  const Cutoffs cut =
      cutoffs(conics.data_ptr<float>(), opacities.data_ptr<float>(), radii.data_ptr<int32_t>(), C, N, slot, V);
  const Inputs in{means2d.data_ptr<float>(), conics.data_ptr<float>(), colors.data_ptr<float>(),
                  opacities.data_ptr<float>(), depths.data_ptr<float>(), cut.disc.data(), cut.sigma.data(),
                  slot.data(), N};
  auto f = torch::TensorOptions().dtype(torch::kFloat32);
  auto image = torch::zeros({C, H, W, 3}, f), alpha = torch::zeros({C, H, W, 1}, f), depth = torch::zeros({C, H, W, 1}, f);
  auto T_final = torch::ones({C, H, W}, f);
  auto last = torch::zeros({C, H, W}, torch::TensorOptions().dtype(torch::kInt32));
  float *img = image.data_ptr<float>(), *al = alpha.data_ptr<float>(), *dep = depth.data_ptr<float>(), *Tf = T_final.data_ptr<float>();
  int32_t* ls = last.data_ptr<int32_t>();
  const int64_t tiles = ((W + tile - 1) / tile) * ((H + tile - 1) / tile);
  const int64_t n_threads = want_contrib ? at::get_num_threads() : 0;
  std::unique_ptr<float[]> contrib_buf = zeroed_buffers(n_threads, V * 3);  // per thread and visible pair: sum, max, max T
  const int64_t bpt = blocks_per_tile(tile);
  auto block_start = torch::empty({C * tiles * bpt + 1}, torch::TensorOptions().dtype(torch::kInt64));
  int64_t* bs = block_start.data_ptr<int64_t>();  // block counts first, then turned into starts below
  std::vector<std::vector<int32_t>> tile_lists(C * tiles);  // a tile's block lists, one after another
  at::parallel_for(0, C * tiles, 1, [&](int64_t b, int64_t e) {
    float* acc = want_contrib ? contrib_buf.get() + at::get_thread_num() * V * 3 : nullptr;
    TileGaussians G;
    BlockLists L;
    BlockOut px;
    std::vector<float> tile_contrib;  // 3 per tile Gaussian
    for (int64_t t = b; t < e; ++t) {
      const int64_t c = t / tiles, n_g = bins.offsets[t + 1] - bins.offsets[t];
      G.gather(bins.ids.data() + bins.offsets[t], n_g, c, in);
      build_block_lists(L, G, t % tiles, W, H, tile);
      std::vector<int32_t>& kept = tile_lists[t];
      for (int64_t k = 0; k < bpt; ++k) {
        bs[t * bpt + k] = k < L.n_blocks ? L.count[k] : 0;
        if (k < L.n_blocks) kept.insert(kept.end(), L.list(k), L.list(k) + L.count[k]);
      }
      if (want_contrib) tile_contrib.assign(3 * n_g, 0.f);
      int64_t blk = 0;
      for_each_block(t % tiles, W, H, tile, [&](int64_t i0, int64_t i1, int64_t j0, int64_t j1) {
        if (want_contrib) composite_block<true>(G, L.list(blk), L.count[blk], i0, i1, j0, j1, px, tile_contrib.data());
        else composite_block<false>(G, L.list(blk), L.count[blk], i0, i1, j0, j1, px, nullptr);
        ++blk;
        for (int64_t i = i0; i < i1; ++i)
          for (int64_t j = j0; j < j1; ++j) {
            const int64_t q = (i - i0) * BLOCK + (j - j0), v = q / 8, u = q % 8, p = (c * H + i) * W + j;
            img[p * 3] = px.r[v][u]; img[p * 3 + 1] = px.g[v][u]; img[p * 3 + 2] = px.b[v][u];
            dep[p] = px.d[v][u]; al[p] = 1.f - px.T[v][u]; Tf[p] = px.T[v][u];
            ls[p] = (int32_t)px.end[v][u];  // end indexes the block's list
          }
      });
      for (int64_t l = 0; want_contrib && l < n_g; ++l) {  // one scatter per tile into this thread's buffer
        float* a = acc + (int64_t)slot[c * N + G.id[l]] * 3;
        const float* q = tile_contrib.data() + 3 * l;
        a[0] += q[0]; a[1] = std::max(a[1], q[1]); a[2] = std::max(a[2], q[2]);
      }
    }
  });
  int64_t run = 0;  // block counts -> starts in block_pos
  for (int64_t k = 0; k < C * tiles * bpt; ++k) {
    const int64_t count = bs[k];
    bs[k] = run;
    run += count;
  }
  bs[C * tiles * bpt] = run;
  auto block_pos = torch::empty({run}, torch::TensorOptions().dtype(torch::kInt32));
  int32_t* bp = block_pos.data_ptr<int32_t>();
  at::parallel_for(0, C * tiles, 16, [&](int64_t b, int64_t e) {
    for (int64_t t = b; t < e; ++t) std::copy(tile_lists[t].begin(), tile_lists[t].end(), bp + bs[t * bpt]);
  });
  auto offsets = torch::from_blob((void*)bins.offsets.data(), {(int64_t)bins.offsets.size()}, torch::kInt64).clone();
  auto ids = torch::from_blob((void*)bins.ids.data(), {(int64_t)bins.ids.size()}, torch::kInt32).clone();
  auto w_sum = torch::zeros({want_contrib ? C : 0, N}, f), w_max = torch::zeros({want_contrib ? C : 0, N}, f),
       t_max = torch::zeros({want_contrib ? C : 0, N}, f);
  float *ws = w_sum.data_ptr<float>(), *wm = w_max.data_ptr<float>(), *tm = t_max.data_ptr<float>();
  at::parallel_for(0, want_contrib ? C * N : 0, 4096, [&](int64_t b, int64_t e) {
    for (int64_t cn = b; cn < e; ++cn) {
      if (slot[cn] < 0) continue;
      for (int64_t th = 0; th < n_threads; ++th) {
        const float* a = contrib_buf.get() + (th * V + slot[cn]) * 3;
        ws[cn] += a[0]; wm[cn] = std::max(wm[cn], a[1]); tm[cn] = std::max(tm[cn], a[2]);
      }
    }
  });
  return {image, alpha, depth, T_final, last, offsets, ids, block_start, block_pos, w_sum, w_max, t_max};
}

// Gradients w.r.t. means2d [C,N,2], conics [C,N,3], colors [C,N,3], opacities [N], depths [C,N]; 0 for culled pairs.
// Each thread sums its tiles' gradients into its own buffer of 10 floats per visible pair (radius > 0: a fraction
// of C N in a narrow view, so the buffers that are zeroed and reduced every step shrink with it), then the threads'
// buffers are reduced into the outputs, pair by pair.
std::vector<torch::Tensor> backward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor colors,
                                    torch::Tensor opacities, torch::Tensor depths, torch::Tensor radii,
                                    torch::Tensor T_final, torch::Tensor last, torch::Tensor offsets, torch::Tensor ids,
                                    torch::Tensor block_start, torch::Tensor block_pos, torch::Tensor g_image,
                                    torch::Tensor g_alpha, torch::Tensor g_depth, int64_t W, int64_t H, int64_t tile) {
  const int64_t C = means2d.size(0), N = means2d.size(1), CN = C * N;
  const float* Tf = T_final.data_ptr<float>();
  const int32_t* ls = last.data_ptr<int32_t>();
  const int64_t* off = offsets.data_ptr<int64_t>();
  const int32_t* gid = ids.data_ptr<int32_t>();
  const int32_t* rad = radii.data_ptr<int32_t>();
  const float *gi = g_image.data_ptr<float>(), *ga = g_alpha.data_ptr<float>(), *gd = g_depth.data_ptr<float>();
  const int64_t* bs = block_start.data_ptr<int64_t>();
  const int32_t* bp = block_pos.data_ptr<int32_t>();
  const Inputs in{means2d.data_ptr<float>(), conics.data_ptr<float>(), colors.data_ptr<float>(),
                  opacities.data_ptr<float>(), depths.data_ptr<float>(), nullptr, nullptr, nullptr, N};
  int32_t V = 0;
  const std::vector<int32_t> slot = visible_slots(rad, CN, V);
  const int64_t threads = at::get_num_threads();
  constexpr int64_t G = 10;  // per visible pair: means2d x y, conic a b c, rgb, z, opacity
  const int64_t bpt = blocks_per_tile(tile);
  TORCH_CHECK(block_start.numel() == C * ((W + tile - 1) / tile) * ((H + tile - 1) / tile) * bpt + 1,
              "compositing backward: block_start does not match the forward's tiles");
  std::unique_ptr<float[]> buf = zeroed_buffers(threads, V * G);
  const int64_t tiles = ((W + tile - 1) / tile) * ((H + tile - 1) / tile);
  at::parallel_for(0, C * tiles, 1, [&](int64_t b, int64_t e) {
    float* acc = buf.get() + at::get_thread_num() * V * G;
    TileGaussians Gs;
    BlockGrad px;
    std::vector<float> grad;  // this tile's gradients, G per tile Gaussian
    for (int64_t t = b; t < e; ++t) {
      const int64_t c = t / tiles;
      const int64_t n_g = off[t + 1] - off[t];
      Gs.gather(gid + off[t], n_g, c, in);
      grad.assign(n_g * G, 0.f);
      int64_t blk = 0;
      for_each_block(t % tiles, W, H, tile, [&](int64_t i0, int64_t i1, int64_t j0, int64_t j1) {
        const int32_t* list = bp + bs[t * bpt + blk++];
        for (int64_t q = 0; q < LANES; ++q) {
          const int64_t i = i0 + q / BLOCK, j = j0 + q % BLOCK, p = (c * H + i) * W + j, v = q / 8, u = q % 8;
          const bool inside = i < i1 && j < j1;
          px.gr[v][u] = inside ? gi[p * 3] : 0.f; px.gg[v][u] = inside ? gi[p * 3 + 1] : 0.f;
          px.gb[v][u] = inside ? gi[p * 3 + 2] : 0.f; px.gz[v][u] = inside ? gd[p] : 0.f;
          px.ga[v][u] = inside ? ga[p] : 0.f; px.T_end[v][u] = inside ? Tf[p] : 1.f;
          px.end[v][u] = inside ? (float)ls[p] : 0.f;
        }
        composite_block_backward(Gs, list, i0, j0, px, grad.data());
      });
      for (int64_t l = 0; l < n_g; ++l) {  // one scatter per tile into this thread's buffer
        float* a = acc + (int64_t)slot[c * N + Gs.id[l]] * G;
        for (int64_t k = 0; k < G; ++k) a[k] += grad[l * G + k];
      }
    }
  });
  auto f = torch::TensorOptions().dtype(torch::kFloat32);
  // every row is written below, zeros for the culled pairs: no zero-fill first (13 MB a step at 330k Gaussians)
  auto gm = torch::empty({C, N, 2}, f), gc = torch::empty({C, N, 3}, f), gcol = torch::empty({C, N, 3}, f),
       gz = torch::empty({C, N}, f), go = torch::empty({N}, f);
  float *pm = gm.data_ptr<float>(), *pc = gc.data_ptr<float>(), *pcol = gcol.data_ptr<float>(),
        *pz = gz.data_ptr<float>(), *po = go.data_ptr<float>();
  at::parallel_for(0, N, 4096, [&](int64_t b, int64_t e) {  // by Gaussian: its cameras' opacity terms sum in one place
    for (int64_t n = b; n < e; ++n) {
      float g_op = 0.f;
      for (int64_t c = 0; c < C; ++c) {
        const int64_t cn = c * N + n;
        float sum[G] = {0};
        for (int64_t th = 0; slot[cn] >= 0 && th < threads; ++th) {
          const float* a = buf.get() + (th * V + slot[cn]) * G;
          for (int64_t k = 0; k < G; ++k) sum[k] += a[k];
        }
        pm[cn * 2] = sum[0]; pm[cn * 2 + 1] = sum[1];
        pc[cn * 3] = sum[2]; pc[cn * 3 + 1] = sum[3]; pc[cn * 3 + 2] = sum[4];
        pcol[cn * 3] = sum[5]; pcol[cn * 3 + 1] = sum[6]; pcol[cn * 3 + 2] = sum[7];
        pz[cn] = sum[8]; g_op += sum[9];
      }
      po[n] = g_op;
    }
  });
  return {gm, gc, gcol, go, gz};
}
