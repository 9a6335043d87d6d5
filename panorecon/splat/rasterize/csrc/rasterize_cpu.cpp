// Tiled Gaussian compositing on the CPU: forward and hand-written backward, parallel over tiles.
// Same rules as the PyTorch reference (torch_backend.py): pixel centres at +0.5; alpha = min(0.99, o exp(-sigma));
// alpha < 1/255 or sigma < 0 skipped; stop before the Gaussian that would take T to <= 1e-4.
// Float32 throughout. Gradients are accumulated in one buffer per thread and summed at the end.
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <algorithm>
#include <cmath>
#include <vector>

namespace {
constexpr float ALPHA_MIN = 1.0f / 255.0f;
constexpr float ALPHA_MAX = 0.99f;
constexpr float T_MIN = 1e-4f;

struct Bins {
  std::vector<int64_t> offsets;  // [C * tiles + 1]
  std::vector<int32_t> ids;      // Gaussian ids, per tile front to back
};

Bins bin(const float* m2d, const float* depth, const int32_t* radii, int64_t C, int64_t N, int64_t W, int64_t H,
         int64_t tile) {
  const int64_t tx_n = (W + tile - 1) / tile, ty_n = (H + tile - 1) / tile, tiles = tx_n * ty_n;
  std::vector<std::vector<int32_t>> lists(C * tiles);
  for (int64_t c = 0; c < C; ++c) {
    for (int64_t n = 0; n < N; ++n) {
      const int32_t r = radii[c * N + n];
      if (r <= 0) continue;
      const float mx = m2d[(c * N + n) * 2], my = m2d[(c * N + n) * 2 + 1];
      // the same touch test as the reference: [m - r, m + r] overlaps [t, t + size]
      int64_t x0 = std::max<int64_t>(0, (int64_t)std::floor((mx - r) / tile));
      int64_t x1 = std::min<int64_t>(tx_n - 1, (int64_t)std::floor((mx + r) / tile));
      int64_t y0 = std::max<int64_t>(0, (int64_t)std::floor((my - r) / tile));
      int64_t y1 = std::min<int64_t>(ty_n - 1, (int64_t)std::floor((my + r) / tile));
      for (int64_t ty = y0; ty <= y1; ++ty)
        for (int64_t tx = x0; tx <= x1; ++tx) {
          const float left = tx * tile, right = std::min<int64_t>(W, (tx + 1) * tile);
          const float top = ty * tile, bottom = std::min<int64_t>(H, (ty + 1) * tile);
          if (mx + r >= left && mx - r <= right && my + r >= top && my - r <= bottom)
            lists[c * tiles + ty * tx_n + tx].push_back((int32_t)n);
        }
    }
  }
  at::parallel_for(0, C * tiles, 1, [&](int64_t b, int64_t e) {
    for (int64_t t = b; t < e; ++t) {
      const float* dz = depth + (t / tiles) * N;
      std::stable_sort(lists[t].begin(), lists[t].end(), [dz](int32_t a, int32_t b2) { return dz[a] < dz[b2]; });
    }
  });
  Bins out;
  out.offsets.resize(C * tiles + 1, 0);
  for (int64_t t = 0; t < C * tiles; ++t) out.offsets[t + 1] = out.offsets[t] + (int64_t)lists[t].size();
  out.ids.resize(out.offsets.back());
  for (int64_t t = 0; t < C * tiles; ++t) std::copy(lists[t].begin(), lists[t].end(), out.ids.begin() + out.offsets[t]);
  return out;
}

// Squared pixel distance beyond which a Gaussian's alpha is surely below 1/255:
// sigma >= 0.5 lambda_min(conic) |d|^2, and o exp(-sigma) < 1/255 once sigma > ln(255 o). -1: never visible.
std::vector<float> cutoffs(const float* con, const float* op, int64_t C, int64_t N) {
  std::vector<float> cut(C * N);
  at::parallel_for(0, C * N, 4096, [&](int64_t b, int64_t e) {
    for (int64_t cn = b; cn < e; ++cn) {
      const float o = op[cn % N];
      const float a = con[cn * 3], bb = con[cn * 3 + 1], c = con[cn * 3 + 2];
      const float mid = 0.5f * (a + c), det = a * c - bb * bb;
      const float lmin = mid - std::sqrt(std::max(mid * mid - det, 0.f));
      if (o * 255.f <= 1.f) { cut[cn] = -1.f; continue; }
      // a small margin keeps the test conservative under float rounding
      cut[cn] = lmin > 0.f ? 2.f * std::log(o * 255.f) / lmin * 1.001f + 1e-3f : INFINITY;
    }
  });
  return cut;
}

constexpr int64_t BLOCK = 4;  // pixels per side of the sub-tile blocks that pre-filter a tile's list

// The tile's depth-ordered ids whose cutoff disc reaches the block of pixel centres [x0, x1] x [y0, y1].
void block_list(const int32_t* ids, int64_t n_ids, const float* m2d, const float* cut, int64_t c, int64_t N, float x0,
                float x1, float y0, float y1, std::vector<int32_t>& out) {
  out.clear();
  for (int64_t k = 0; k < n_ids; ++k) {
    const int64_t cn = c * N + ids[k];
    const float mx = m2d[cn * 2], my = m2d[cn * 2 + 1];
    const float dx = std::max(std::max(x0 - mx, mx - x1), 0.f), dy = std::max(std::max(y0 - my, my - y1), 0.f);
    if (dx * dx + dy * dy <= cut[cn]) out.push_back(ids[k]);
  }
}

inline bool alpha_at(const float* con, float dx, float dy, float o, float& alpha, float& vis) {
  const float sigma = 0.5f * (con[0] * dx * dx + con[2] * dy * dy) + con[1] * dx * dy;
  if (sigma < 0.f) return false;
  vis = std::exp(-sigma);
  alpha = std::min(ALPHA_MAX, o * vis);
  return alpha >= ALPHA_MIN;
}
}  // namespace

// -> image [C,H,W,3], alpha [C,H,W,1], depth [C,H,W,1], T_final [C,H,W], last [C,H,W] (int32: how many
// entries of the pixel's 4x4-block list were composited), offsets, ids, and with want_contrib the per-Gaussian
// weight_sum, weight_max (sum / max over pixels of alpha*T) and trans_max (max T in front of it where it was
// composited) [C,N]; else three empty tensors. Contributions are reduced from per-thread buffers.
std::vector<torch::Tensor> forward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor colors,
                                   torch::Tensor opacities, torch::Tensor depths, torch::Tensor radii, int64_t W,
                                   int64_t H, int64_t tile, bool want_contrib) {
  const int64_t C = means2d.size(0), N = means2d.size(1);
  const float* m2d = means2d.data_ptr<float>();
  const float* con = conics.data_ptr<float>();
  const float* col = colors.data_ptr<float>();
  const float* op = opacities.data_ptr<float>();
  const float* dz = depths.data_ptr<float>();
  Bins bins = bin(m2d, dz, radii.data_ptr<int32_t>(), C, N, W, H, tile);
  const std::vector<float> cut = cutoffs(con, op, C, N);
  auto f = torch::TensorOptions().dtype(torch::kFloat32);
  auto image = torch::zeros({C, H, W, 3}, f), alpha = torch::zeros({C, H, W, 1}, f), depth = torch::zeros({C, H, W, 1}, f);
  auto T_final = torch::ones({C, H, W}, f);
  auto last = torch::zeros({C, H, W}, torch::TensorOptions().dtype(torch::kInt32));
  float *img = image.data_ptr<float>(), *al = alpha.data_ptr<float>(), *dep = depth.data_ptr<float>(), *Tf = T_final.data_ptr<float>();
  int32_t* ls = last.data_ptr<int32_t>();
  const int64_t tx_n = (W + tile - 1) / tile, ty_n = (H + tile - 1) / tile, tiles = tx_n * ty_n;
  const int64_t n_threads = want_contrib ? at::get_num_threads() : 0;
  // per thread: [weight_sum | weight_max | trans_max] x C*N
  std::vector<float> contrib_buf(n_threads * 3 * C * N, 0.f);
  at::parallel_for(0, C * tiles, 1, [&](int64_t b, int64_t e) {
    float* cb = want_contrib ? contrib_buf.data() + at::get_thread_num() * 3 * C * N : nullptr;
    for (int64_t t = b; t < e; ++t) {
      const int64_t c = t / tiles, ty = (t % tiles) / tx_n, tx = (t % tiles) % tx_n;
      const int64_t s = bins.offsets[t], n_g = bins.offsets[t + 1] - s;
      std::vector<int32_t> list;
      for (int64_t bi = ty * tile; bi < std::min<int64_t>(H, (ty + 1) * tile); bi += BLOCK)
        for (int64_t bj = tx * tile; bj < std::min<int64_t>(W, (tx + 1) * tile); bj += BLOCK) {
          const int64_t ei = std::min<int64_t>({H, (ty + 1) * tile, bi + BLOCK});
          const int64_t ej = std::min<int64_t>({W, (tx + 1) * tile, bj + BLOCK});
          block_list(bins.ids.data() + s, n_g, m2d, cut.data(), c, N, bj + 0.5f, ej - 0.5f, bi + 0.5f, ei - 0.5f, list);
          const int64_t n_l = (int64_t)list.size();
          for (int64_t i = bi; i < ei; ++i)
            for (int64_t j = bj; j < ej; ++j) {
              const float px = j + 0.5f, py = i + 0.5f;
              float T = 1.f, r = 0.f, g = 0.f, bl = 0.f, d = 0.f;
              int32_t end = 0;
              for (int64_t k = 0; k < n_l; ++k) {
                const int64_t n = list[k], cn = c * N + n;
                const float dx = px - m2d[cn * 2], dy = py - m2d[cn * 2 + 1];
                if (dx * dx + dy * dy > cut[cn]) continue;
                float a, vis;
                if (!alpha_at(con + cn * 3, dx, dy, op[n], a, vis)) continue;
                const float nextT = T * (1.f - a);
                if (nextT <= T_MIN) break;
                const float w = a * T;
                if (cb) {
                  cb[cn] += w;
                  cb[C * N + cn] = std::max(cb[C * N + cn], w);
                  cb[2 * C * N + cn] = std::max(cb[2 * C * N + cn], T);
                }
                r += w * col[cn * 3];
                g += w * col[cn * 3 + 1];
                bl += w * col[cn * 3 + 2];
                d += w * dz[cn];
                T = nextT;
                end = (int32_t)(k + 1);
              }
              const int64_t p = (c * H + i) * W + j;
              img[p * 3] = r; img[p * 3 + 1] = g; img[p * 3 + 2] = bl;
              dep[p] = d; al[p] = 1.f - T; Tf[p] = T; ls[p] = end;  // end indexes the block's list
            }
        }
    }
  });
  auto offsets = torch::from_blob(bins.offsets.data(), {(int64_t)bins.offsets.size()}, torch::kInt64).clone();
  auto ids = torch::from_blob(bins.ids.data(), {(int64_t)bins.ids.size()}, torch::kInt32).clone();
  auto w_sum = torch::zeros({want_contrib ? C : 0, N}, f), w_max = torch::zeros({want_contrib ? C : 0, N}, f),
       t_max = torch::zeros({want_contrib ? C : 0, N}, f);
  float *ws = w_sum.data_ptr<float>(), *wm = w_max.data_ptr<float>(), *tm = t_max.data_ptr<float>();
  for (int64_t th = 0; th < n_threads; ++th) {
    const float* cb = contrib_buf.data() + th * 3 * C * N;
    for (int64_t k = 0; k < C * N; ++k) {
      ws[k] += cb[k];
      wm[k] = std::max(wm[k], cb[C * N + k]);
      tm[k] = std::max(tm[k], cb[2 * C * N + k]);
    }
  }
  return {image, alpha, depth, T_final, last, offsets, ids, w_sum, w_max, t_max};
}

// Gradients w.r.t. means2d [C,N,2], conics [C,N,3], colors [C,N,3], opacities [N], depths [C,N].
std::vector<torch::Tensor> backward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor colors,
                                    torch::Tensor opacities, torch::Tensor depths, torch::Tensor T_final,
                                    torch::Tensor last, torch::Tensor offsets, torch::Tensor ids, torch::Tensor g_image,
                                    torch::Tensor g_alpha, torch::Tensor g_depth, int64_t W, int64_t H, int64_t tile) {
  const int64_t C = means2d.size(0), N = means2d.size(1);
  const float *m2d = means2d.data_ptr<float>(), *con = conics.data_ptr<float>(), *col = colors.data_ptr<float>();
  const float *op = opacities.data_ptr<float>(), *dz = depths.data_ptr<float>(), *Tf = T_final.data_ptr<float>();
  const int32_t* ls = last.data_ptr<int32_t>();
  const int64_t* off = offsets.data_ptr<int64_t>();
  const int32_t* gid = ids.data_ptr<int32_t>();
  const float *gi = g_image.data_ptr<float>(), *ga = g_alpha.data_ptr<float>(), *gd = g_depth.data_ptr<float>();
  const std::vector<float> cut = cutoffs(con, op, C, N);
  const int64_t threads = at::get_num_threads();
  // per thread: means2d 2, conics 3, colors 3, depth 1 per (c, n); opacity 1 per n
  const int64_t stride = C * N * 9 + N;
  std::vector<float> buf(threads * stride, 0.f);
  const int64_t tx_n = (W + tile - 1) / tile, ty_n = (H + tile - 1) / tile, tiles = tx_n * ty_n;
  at::parallel_for(0, C * tiles, 1, [&](int64_t b, int64_t e) {
    float* acc = buf.data() + at::get_thread_num() * stride;
    float *gm = acc, *gc = acc + C * N * 2, *gcol = acc + C * N * 5, *gz = acc + C * N * 8, *go = acc + C * N * 9;
    for (int64_t t = b; t < e; ++t) {
      const int64_t c = t / tiles, ty = (t % tiles) / tx_n, tx = (t % tiles) % tx_n;
      const int64_t s = off[t], n_g = off[t + 1] - s;
      std::vector<int32_t> list;
      for (int64_t bi = ty * tile; bi < std::min<int64_t>(H, (ty + 1) * tile); bi += BLOCK)
        for (int64_t bj = tx * tile; bj < std::min<int64_t>(W, (tx + 1) * tile); bj += BLOCK) {
          const int64_t ei = std::min<int64_t>({H, (ty + 1) * tile, bi + BLOCK});
          const int64_t ej = std::min<int64_t>({W, (tx + 1) * tile, bj + BLOCK});
          block_list(gid + s, n_g, m2d, cut.data(), c, N, bj + 0.5f, ej - 0.5f, bi + 0.5f, ei - 0.5f, list);
          for (int64_t i = bi; i < ei; ++i)
            for (int64_t j = bj; j < ej; ++j) {
              const int64_t p = (c * H + i) * W + j;
              const float px = j + 0.5f, py = i + 0.5f;
              const float gr = gi[p * 3], gg = gi[p * 3 + 1], gb = gi[p * 3 + 2], gdp = gd[p], gal = ga[p];
              const float T_end = Tf[p];
              float T = T_end;                              // transmittance after the current Gaussian
              float Sr = 0.f, Sg = 0.f, Sb = 0.f, Sd = 0.f;  // what lies behind it
              for (int64_t k = (int64_t)ls[p] - 1; k >= 0; --k) {
                const int64_t n = list[k], cn = c * N + n;
                const float* q = con + cn * 3;
                const float dx = px - m2d[cn * 2], dy = py - m2d[cn * 2 + 1];
                if (dx * dx + dy * dy > cut[cn]) continue;
                float a, vis;
                if (!alpha_at(q, dx, dy, op[n], a, vis)) continue;
                const float Tb = T / (1.f - a);  // transmittance before it
                const float w = a * Tb;
                const float* cc = col + cn * 3;
                gcol[cn * 3] += w * gr; gcol[cn * 3 + 1] += w * gg; gcol[cn * 3 + 2] += w * gb;
                gz[cn] += w * gdp;
                const float g_a = Tb * (cc[0] * gr + cc[1] * gg + cc[2] * gb + dz[cn] * gdp)
                                  - (Sr * gr + Sg * gg + Sb * gb + Sd * gdp) / (1.f - a) + gal * T_end / (1.f - a);
                Sr += w * cc[0]; Sg += w * cc[1]; Sb += w * cc[2]; Sd += w * dz[cn];
                T = Tb;
                if (op[n] * vis > ALPHA_MAX) continue;  // clamped alpha: no gradient to opacity or shape
                go[n] += vis * g_a;
                const float g_sigma = -op[n] * vis * g_a;
                gc[cn * 3] += 0.5f * dx * dx * g_sigma;
                gc[cn * 3 + 1] += dx * dy * g_sigma;
                gc[cn * 3 + 2] += 0.5f * dy * dy * g_sigma;
                gm[cn * 2] += -(q[0] * dx + q[1] * dy) * g_sigma;
                gm[cn * 2 + 1] += -(q[1] * dx + q[2] * dy) * g_sigma;
              }
            }
        }
    }
  });
  auto f = torch::TensorOptions().dtype(torch::kFloat32);
  auto out = torch::zeros({stride}, f);
  float* o = out.data_ptr<float>();
  for (int64_t th = 0; th < threads; ++th)
    for (int64_t k = 0; k < stride; ++k) o[k] += buf[th * stride + k];
  return {out.narrow(0, 0, C * N * 2).view({C, N, 2}), out.narrow(0, C * N * 2, C * N * 3).view({C, N, 3}),
          out.narrow(0, C * N * 5, C * N * 3).view({C, N, 3}), out.narrow(0, C * N * 9, N).clone(),
          out.narrow(0, C * N * 8, C * N).view({C, N})};
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("forward", &forward, "tiled Gaussian compositing, forward");
  m.def("backward", &backward, "tiled Gaussian compositing, backward");
}
