// Flattening onto the given cloud's surface (splat/regularisers.py flatten_onto_surface) on the CPU: each Gaussian
// in float64 registers, in one pass, the formula of regularisers.flatten_onto_surface_torch step for step (its bin
// from its ray, the 2 x 2 matrix of its sheared covariance on the bin's basis, the matrix's angle and eigenvalues,
// the disc's rotation and its quaternion by Shepperd's method). One call at 524,278 Gaussians took 0.12-0.13 CPU
// seconds here against 1.45 for the numpy code it replaced (least of 7 calls, a shared 2-core machine, 2026-11-28);
// the torch formula, some 200 passes over [N] float64 arrays, takes about as long as that numpy code on a CPU.
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <cmath>

namespace {
constexpr double PI = 3.14159265358979323846;

void flatten(const float* __restrict means, float* __restrict quats, float* __restrict log_scales,
             bool* __restrict flat, const double* __restrict frames, int64_t N, int64_t H, double thickness,
             double min_cos) {
  const int64_t W = 2 * H;
  at::parallel_for(0, N, 8192, [=](int64_t b, int64_t e) {
    for (int64_t g = b; g < e; ++g) {
      const double mx = means[3 * g], my = means[3 * g + 1], mz = means[3 * g + 2];
      const double r = std::sqrt(mx * mx + my * my + mz * mz);
      if (!(r > 0) || !std::isfinite(r)) continue;
      const double u[3] = {mx / r, my / r, mz / r};
      // its ERP bin (geometry/sphere.py direction_to_erp_pixel, rounded half to even as torch.round)
      const double lon = std::atan2(-u[1], u[0]), lat = std::atan2(u[2], std::sqrt(u[0] * u[0] + u[1] * u[1]));
      const double row = (0.5 - lat / PI) * H - 0.5, col = (lon / (2 * PI) + 0.5) * W - 0.5;
      const int64_t ri = std::min<int64_t>(std::max<int64_t>((int64_t)std::nearbyint(row), 0), H - 1);
      const int64_t ci = (((int64_t)std::nearbyint(col) % W) + W) % W;
      const double* f = frames + (ri * W + ci) * 9;  // t1, t2, n
      const double* n = f + 6;
      const double cos = n[0] * u[0] + n[1] * u[1] + n[2] * u[2];
      if (!(std::abs(cos) >= min_cos)) continue;  // grazing, or a bin without a normal (NaN)
      // R from the quaternion as rasterize/projection.py quat_to_rotmat (a zero or NaN norm: the identity)
      double w = quats[4 * g], x = quats[4 * g + 1], y = quats[4 * g + 2], z = quats[4 * g + 3];
      const double qn = std::sqrt(w * w + x * x + y * y + z * z);
      if (qn > 1e-12) {
        w /= qn, x /= qn, y /= qn, z /= qn;
      } else {
        w = 1, x = 0, y = 0, z = 0;
      }
      const double R[3][3] = {{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
                              {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
                              {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}};
      double s2[3];
      bool finite = true;
      for (int k = 0; k < 3; ++k) {
        s2[k] = std::exp(2 * (double)log_scales[3 * g + k]);
        finite = finite && std::isfinite(s2[k]);
        for (int j = 0; j < 3; ++j) finite = finite && std::isfinite(R[j][k]);
      }
      if (!finite) continue;
      // c_ik = p_i · R_k with p_i = t_i - n (t_i · u) / cos; m = the 2 x 2 matrix sum_k c_ik c_jk s_k^2
      double c[2][3];
      for (int i = 0; i < 2; ++i) {
        const double* t = f + 3 * i;
        const double a = (t[0] * u[0] + t[1] * u[1] + t[2] * u[2]) / cos;
        const double p[3] = {t[0] - a * n[0], t[1] - a * n[1], t[2] - a * n[2]};
        for (int k = 0; k < 3; ++k) c[i][k] = p[0] * R[0][k] + p[1] * R[1][k] + p[2] * R[2][k];
      }
      double m11 = 0, m22 = 0, m12 = 0;
      for (int k = 0; k < 3; ++k) {
        m11 += c[0][k] * s2[k] * c[0][k];
        m22 += c[1][k] * s2[k] * c[1][k];
        m12 += c[0][k] * s2[k] * c[1][k];
      }
      // the disc's axes e1 (the 2 x 2 matrix's major eigenvector), n x e1 and n, and their quaternion by
      // Shepperd's method, as model.rotmat_to_wxyz (n as given: float32 normals are unit to ~6e-8)
      const double theta = 0.5 * std::atan2(2 * m12, m11 - m22);
      const double mid = (m11 + m22) / 2, half = std::hypot((m11 - m22) / 2, m12);
      const double var[3] = {mid + half, mid - half, thickness * thickness * mid};
      if (!(std::isfinite(theta) && std::isfinite(var[0]) && std::isfinite(var[1]) && std::isfinite(var[2])))
        continue;  // variances past float64's range: left as it is
      const double ct = std::cos(theta), st = std::sin(theta);
      const double* t1 = f;
      const double* t2 = f + 3;
      const double e1[3] = {ct * t1[0] + st * t2[0], ct * t1[1] + st * t2[1], ct * t1[2] + st * t2[2]};
      const double e2[3] = {n[1] * e1[2] - n[2] * e1[1], n[2] * e1[0] - n[0] * e1[2], n[0] * e1[1] - n[1] * e1[0]};
      const double d0 = e1[0], d1 = e2[1], d2 = n[2];  // the diagonal of [e1 e2 n]
      const double big[4] = {1 + d0 + d1 + d2, 1 + d0 - d1 - d2, 1 - d0 + d1 - d2, 1 - d0 - d1 + d2};
      int k = 0;
      for (int j = 1; j < 4; ++j)
        if (big[j] > big[k]) k = j;
      const double s = 2 * std::sqrt(std::max(big[k], 1e-300));  // 4 x the largest component
      const double zy = e2[2], yz = n[1], xz = n[0], zx = e1[2], yx = e1[1], xy = e2[0];
      double q[4];
      if (k == 0) {
        q[0] = s / 4, q[1] = (zy - yz) / s, q[2] = (xz - zx) / s, q[3] = (yx - xy) / s;
      } else if (k == 1) {
        q[0] = (zy - yz) / s, q[1] = s / 4, q[2] = (xy + yx) / s, q[3] = (xz + zx) / s;
      } else if (k == 2) {
        q[0] = (xz - zx) / s, q[1] = (xy + yx) / s, q[2] = s / 4, q[3] = (yz + zy) / s;
      } else {
        q[0] = (yx - xy) / s, q[1] = (xz + zx) / s, q[2] = (yz + zy) / s, q[3] = s / 4;
      }
      const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
      for (int j = 0; j < 4; ++j) quats[4 * g + j] = (float)(q[j] / norm);
      for (int k = 0; k < 3; ++k) log_scales[3 * g + k] = (float)(0.5 * std::log(std::max(var[k], 1e-30)));
      flat[g] = true;
    }
  });
}
}  // namespace

// means [N, 3], quats [N, 4] wxyz and log_scales [N, 3] float32 contiguous (the last two updated in place); frames
// [H * 2H, 9] float64 contiguous (regularisers.flatten_frames) -> [N] bool, the Gaussians flattened.
torch::Tensor flatten_surface(torch::Tensor means, torch::Tensor quats, torch::Tensor log_scales, torch::Tensor frames,
                              int64_t height, double thickness, double min_cos) {
  const int64_t N = means.size(0);
  TORCH_CHECK(means.is_contiguous() && quats.is_contiguous() && log_scales.is_contiguous() && frames.is_contiguous(),
              "flatten_surface: contiguous tensors expected");
  TORCH_CHECK(means.scalar_type() == torch::kFloat32 && quats.scalar_type() == torch::kFloat32 &&
                  log_scales.scalar_type() == torch::kFloat32 && frames.scalar_type() == torch::kFloat64,
              "flatten_surface: float32 means, quats and log_scales and float64 frames expected");
  TORCH_CHECK(means.dim() == 2 && means.size(1) == 3 && quats.sizes() == torch::IntArrayRef({N, 4}) &&
                  log_scales.sizes() == torch::IntArrayRef({N, 3}) &&
                  frames.sizes() == torch::IntArrayRef({2 * height * height, 9}),
              "flatten_surface: means [N, 3], quats [N, 4], log_scales [N, 3] and frames [2 H^2, 9] expected");
  auto flat = torch::zeros({N}, means.options().dtype(torch::kBool));
  flatten(means.data_ptr<float>(), quats.data_ptr<float>(), log_scales.data_ptr<float>(), flat.data_ptr<bool>(),
          frames.data_ptr<double>(), N, height, thickness, min_cos);
  return flat;
}
