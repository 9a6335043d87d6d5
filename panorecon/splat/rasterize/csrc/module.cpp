// The Python module of the cpu backend: projection (project_cpu.cpp), SH colours (sh_cpu.cpp), compositing
// (rasterize_cpu.cpp), the training loss's SSIM (ssim_cpu.cpp), L1 and depth term (loss_cpu.cpp), the densification
// statistic (densify_cpu.cpp), flattening onto the given cloud's surface (flatten_cpu.cpp), and the machine's measured
// limits for the roofline benchmark (peak_cpu.cpp).
#include <torch/extension.h>
#include <vector>

std::vector<torch::Tensor> forward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor colors,
                                   torch::Tensor opacities, torch::Tensor depths, torch::Tensor radii, int64_t W,
                                   int64_t H, int64_t tile, bool want_contrib);
std::vector<torch::Tensor> backward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor colors,
                                    torch::Tensor opacities, torch::Tensor depths, torch::Tensor radii,
                                    torch::Tensor T_final, torch::Tensor last, torch::Tensor offsets, torch::Tensor ids,
                                    torch::Tensor block_start, torch::Tensor block_pos, torch::Tensor g_image,
                                    torch::Tensor g_alpha, torch::Tensor g_depth, int64_t W, int64_t H, int64_t tile);
std::vector<torch::Tensor> project_forward(torch::Tensor means, torch::Tensor quats, torch::Tensor scales,
                                           torch::Tensor viewmats, torch::Tensor Ks, int64_t W, int64_t H,
                                           double near, double far, double eps2d);
std::vector<torch::Tensor> project_backward(torch::Tensor means, torch::Tensor quats, torch::Tensor scales,
                                            torch::Tensor viewmats, torch::Tensor Ks, torch::Tensor radii,
                                            torch::Tensor g_m2d, torch::Tensor g_con, torch::Tensor g_dep, int64_t W,
                                            int64_t H, double near, double far, double eps2d);
torch::Tensor sh_forward(torch::Tensor dc, torch::Tensor rest, torch::Tensor means, torch::Tensor campos,
                         torch::Tensor radii, int64_t degree);
std::vector<torch::Tensor> sh_backward(torch::Tensor dc, torch::Tensor rest, torch::Tensor means,
                                       torch::Tensor campos, torch::Tensor radii, torch::Tensor g_colors,
                                       int64_t degree);
std::vector<torch::Tensor> ssim_forward(torch::Tensor x, torch::Tensor y, torch::Tensor g);
torch::Tensor ssim_backward(torch::Tensor x, torch::Tensor y, torch::Tensor g, torch::Tensor partials,
                            torch::Tensor g_mean);
torch::Tensor l1_forward(torch::Tensor x, torch::Tensor y);
torch::Tensor l1_backward(torch::Tensor x, torch::Tensor y, torch::Tensor g_loss);
std::vector<torch::Tensor> pearson_forward(torch::Tensor x, torch::Tensor y, torch::Tensor valid);
torch::Tensor pearson_backward(torch::Tensor x, torch::Tensor y, torch::Tensor valid, torch::Tensor stats,
                               torch::Tensor g_loss);
void accumulate_screen_grads(torch::Tensor grad_sum, torch::Tensor count, torch::Tensor g_m2d, torch::Tensor radii,
                             double sx, double sy);
torch::Tensor flatten_surface(torch::Tensor means, torch::Tensor quats, torch::Tensor log_scales, torch::Tensor frames,
                              int64_t height, double thickness, double min_cos);
std::vector<double> peak_fma(int64_t iters, int64_t lanes);
std::vector<double> stream_copy(int64_t n, int64_t repeats);

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("forward", &forward, "tiled Gaussian compositing, forward");
  m.def("backward", &backward, "tiled Gaussian compositing, backward");
  m.def("project_forward", &project_forward, "EWA projection, forward");
  m.def("project_backward", &project_backward, "EWA projection, backward");
  m.def("sh_forward", &sh_forward, "SH colours of the visible Gaussians, forward");
  m.def("sh_backward", &sh_backward, "SH colours of the visible Gaussians, backward");
  m.def("ssim_forward", &ssim_forward, "fused SSIM of planar images: mean of the map, and its partials");
  m.def("ssim_backward", &ssim_backward, "fused SSIM, gradient w.r.t. x");
  m.def("l1_forward", &l1_forward, "mean |x - y|");
  m.def("l1_backward", &l1_backward, "mean |x - y|, gradient w.r.t. x");
  m.def("pearson_forward", &pearson_forward, "1 - Pearson correlation of depths over valid pixels, and its statistics");
  m.def("pearson_backward", &pearson_backward, "1 - Pearson correlation, gradient w.r.t. the rendered depth");
  m.def("accumulate_screen_grads", &accumulate_screen_grads,
        "densification statistic in place: sums of NDC 2D-mean gradient norms and counts of the seen pairs");
  m.def("flatten_surface", &flatten_surface, "flattening onto the surface's planes, in place -> [N] bool flattened");
  m.def("peak_fma", &peak_fma, "FMA loop on every thread, 8 or 16 lanes -> [seconds, flops]");
  m.def("stream_copy", &stream_copy, "STREAM-like copy on every thread -> [seconds, bytes]");
}
