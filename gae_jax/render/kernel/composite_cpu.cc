// CPU compositor of tile lists, called from JAX through the XLA FFI (gae_jax.render.cpu_kernel).
//
// The same numerics as gae_jax/render/composite.py (its docstrings define them): per pixel, the
// tile's list is walked nearest first; q = [dx dy] conic [dx dy]^T, alpha = min(clamp, o
// exp(-q/2)), skipped when alpha < 1/255 or q < 0; a pixel stops before the slot that would take
// its transmittance under 1e-4. The backward walks each list back to front as the reference CUDA
// backward does (T recovered as T_{j+1} / (1 - a_j), a slot counts iff it lies before the pixel's
// last composited slot). Per-slot results are written per tile; the Python side scatters them to
// Gaussians, so tiles are independent and run on worker threads. Within a tile the 256 pixels
// are the SIMD lanes (struct-of-arrays state, branch-free selects, a polynomial exp).
//
// Layouts (row-major): table (T, cap) int32, -1 padding; kept (T,) int32; packed (N, 7 + C)
// float32 = mean x, mean y, conic a, b, c, opacity, depth, colour; per-pixel arrays (T, 256[, C])
// in the per-tile layout of composite.pixel_centres.

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <thread>
#include <vector>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

constexpr int kTile = 16;
constexpr int kPixels = kTile * kTile;
constexpr int kGeometry = 7;
constexpr float kAlphaThreshold = 1.0f / 255.0f;
constexpr float kTransmittanceMin = 1e-4f;

enum Mode : int32_t { kStandard = 0, kWabe = 1, kWabeGrad = 2 };

// exp(x) for float32 on [-50, 88] (clamped outside; relative error <= 1.02e-7 against double exp
// on a 1e-5 grid, about 1 ulp),
// written so that loops over pixels vectorise: x = n ln2 + r with |r| <= ln2 / 2 (n an integer),
// a degree-7 Taylor polynomial in r, 2^n from the exponent bits. The floor at -50 keeps products
// like opacity * exp(-q / 2) out of the denormal range, which costs ~100 cycles per operation on
// x86; every use here compares the result with 1/255 or multiplies it by a number <= 1, where
// exp(-50) ~ 2e-22 and 0 are the same answer.
inline float min(float x, float y) { return x < y ? x : y; }  // (std::fmin is a libm call)
inline float max(float x, float y) { return x > y ? x : y; }

inline float fast_exp(float x) {
  x = min(max(x, -50.0f), 88.0f);
  // Round to nearest by the 1.5 * 2^23 shifter (std::floor is a libm call unless traps are off).
  const float n = (x * 1.44269504088896341f + 12582912.0f) - 12582912.0f;
  const float r = (x - n * 0.693145751953125f) - n * 1.428606765330187e-06f;
  float p = 1.0f / 5040.0f;
  p = p * r + 1.0f / 720.0f;
  p = p * r + 1.0f / 120.0f;
  p = p * r + 1.0f / 24.0f;
  p = p * r + 1.0f / 6.0f;
  p = p * r + 0.5f;
  p = p * r + 1.0f;
  p = p * r + 1.0f;
  const int32_t bits = (static_cast<int32_t>(n) + 127) << 23;
  float scale;
  std::memcpy(&scale, &bits, sizeof(scale));
  return p * scale;
}

struct Settings {
  float alpha_clamp;
  int32_t mode;
  float beta;
  int32_t front_contributors;
  float visibility_beta;
  int64_t tiles_x;
  int64_t capacity;
  int64_t channels;
};

// Runs body(tile) for every tile on `threads` workers (0: one per hardware thread).
template <typename Body>
void for_each_tile(int64_t num_tiles, int32_t threads, const Body& body) {
  int64_t workers = threads > 0 ? threads : std::max(1u, std::thread::hardware_concurrency());
  workers = std::min<int64_t>(workers, num_tiles);
  std::atomic<int64_t> next{0};
  auto work = [&]() {
    for (int64_t tile = next++; tile < num_tiles; tile = next++) body(tile);
  };
  std::vector<std::thread> pool;
  for (int64_t i = 1; i < workers; ++i) pool.emplace_back(work);
  work();
  for (auto& t : pool) t.join();
}

void pixel_centres(const Settings& s, int64_t tile, float* px, float* py) {
  const float ox = static_cast<float>((tile % s.tiles_x) * kTile);
  const float oy = static_cast<float>((tile / s.tiles_x) * kTile);
  for (int p = 0; p < kPixels; ++p) {
    px[p] = ox + static_cast<float>(p % kTile) + 0.5f;
    py[p] = oy + static_cast<float>(p / kTile) + 0.5f;
  }
}

struct ForwardOut {
  float* color;
  float* transmittance;
  float* depth;
  int32_t* last;
  float* pixels;
  float* visibility;
};

template <bool kWeighted, bool kFront>
void forward_tile(const Settings& s, int64_t tile, const int32_t* table, int32_t kept,
                  const float* packed, const ForwardOut& out) {
  const int64_t C = s.channels, K = kGeometry + C, cap = s.capacity;
  alignas(64) float px[kPixels], py[kPixels], T[kPixels], depth[kPixels], weight[kPixels];
  alignas(64) int32_t done[kPixels], last[kPixels], seen[kPixels];
  std::vector<float> color(C * kPixels, 0.0f);
  pixel_centres(s, tile, px, py);
  for (int p = 0; p < kPixels; ++p) {
    T[p] = 1.0f;
    depth[p] = 0.0f;
    done[p] = 0;
    last[p] = 0;
    seen[p] = 0;
  }
  float* pixels = out.pixels + tile * cap;
  float* visibility = out.visibility + tile * cap;
  std::fill(pixels, pixels + cap, 0.0f);
  std::fill(visibility, visibility + cap, 0.0f);
  for (int32_t j = 0; j < kept; ++j) {
    const int32_t index = table[tile * cap + j];
    if (index < 0) continue;
    const float* g = packed + static_cast<int64_t>(index) * K;
    const float mx = g[0], my = g[1], a = g[2], b = g[3], c = g[4], o = g[5], d = g[6];
    float used = 0.0f, vis_max = 0.0f;
    int32_t finished = 0;
#pragma omp simd reduction(+ : used, finished) reduction(max : vis_max)
    for (int p = 0; p < kPixels; ++p) {
      const float dx = px[p] - mx, dy = py[p] - my;
      const float q = a * dx * dx + 2.0f * b * dx * dy + c * dy * dy;
      const float alpha = min(s.alpha_clamp, o * fast_exp(-0.5f * q));
      const bool valid = (alpha >= kAlphaThreshold) & (q >= 0.0f);
      const float t = T[p];
      const float t_next = t * (1.0f - alpha);
      const bool live = valid & (done[p] == 0);
      const bool stop = live & (t_next < kTransmittanceMin);
      const bool use = live & !stop;
      const float contrib = use ? alpha * t : 0.0f;
      weight[p] = kWeighted ? contrib * fast_exp(-s.beta * (1.0f - t)) : contrib;
      depth[p] += contrib * d;
      last[p] = use ? j + 1 : last[p];
      if (kFront) {
        const bool first = use & (seen[p] < s.front_contributors);
        const float v = first ? fast_exp(-s.visibility_beta * (1.0f - t)) * alpha : 0.0f;
        vis_max = max(vis_max, v);
        seen[p] += use ? 1 : 0;
      }
      done[p] = (done[p] != 0) | stop;
      T[p] = use ? t_next : t;
      used += use ? 1.0f : 0.0f;
      finished += done[p];
    }
    for (int64_t ch = 0; ch < C; ++ch) {
      const float value = g[kGeometry + ch];
      float* plane = color.data() + ch * kPixels;
#pragma omp simd
      for (int p = 0; p < kPixels; ++p) plane[p] += weight[p] * value;
    }
    pixels[j] = used;
    visibility[j] = vis_max;
    if (finished == kPixels) break;
  }
  const int64_t base = tile * kPixels;
  for (int p = 0; p < kPixels; ++p) {
    out.transmittance[base + p] = T[p];
    out.depth[base + p] = depth[p];
    out.last[base + p] = last[p];
    for (int64_t ch = 0; ch < C; ++ch) out.color[(base + p) * C + ch] = color[ch * kPixels + p];
  }
}

struct BackwardIn {
  const float* t_final;
  const int32_t* last;
  const float* g_color;
  const float* g_transmittance;
  const float* g_depth;
};

template <int32_t mode>
void backward_tile(const Settings& s, int64_t tile, const int32_t* table, const float* packed,
                   const BackwardIn& in, float* grads) {
  const int64_t C = s.channels, K = kGeometry + C, cap = s.capacity;
  std::fill(grads + tile * cap * K, grads + (tile + 1) * cap * K, 0.0f);
  alignas(64) float px[kPixels], py[kPixels], T[kPixels], Q[kPixels], g_depth[kPixels];
  alignas(64) float gc_dot[kPixels], colour_weight[kPixels];
  alignas(64) int32_t last[kPixels];
  std::vector<float> g_color(C * kPixels);
  pixel_centres(s, tile, px, py);
  const int64_t base = tile * kPixels;
  int32_t top = 0;
  for (int p = 0; p < kPixels; ++p) {
    T[p] = in.t_final[base + p];
    Q[p] = in.g_transmittance[base + p] * T[p];
    g_depth[p] = in.g_depth[base + p];
    last[p] = in.last[base + p];
    top = std::max(top, last[p]);
    for (int64_t ch = 0; ch < C; ++ch)
      g_color[ch * kPixels + p] = in.g_color[(base + p) * C + ch];
  }
  const float beta = s.beta, clamp = s.alpha_clamp;
  for (int32_t j = top - 1; j >= 0; --j) {
    const int32_t index = table[tile * cap + j];
    if (index < 0) continue;
    const float* g = packed + static_cast<int64_t>(index) * K;
    const float mx = g[0], my = g[1], a = g[2], b = g[3], c = g[4], o = g[5], d = g[6];
    std::fill(gc_dot, gc_dot + kPixels, 0.0f);
    for (int64_t ch = 0; ch < C; ++ch) {
      const float value = g[kGeometry + ch];
      const float* plane = g_color.data() + ch * kPixels;
#pragma omp simd
      for (int p = 0; p < kPixels; ++p) gc_dot[p] += plane[p] * value;
    }
    float s_mx = 0, s_my = 0, s_a = 0, s_b = 0, s_c = 0, s_q = 0, s_depth = 0;
#pragma omp simd reduction(+ : s_mx, s_my, s_a, s_b, s_c, s_q, s_depth)
    for (int p = 0; p < kPixels; ++p) {
      const float dx = px[p] - mx, dy = py[p] - my;
      const float q = a * dx * dx + 2.0f * b * dx * dy + c * dy * dy;
      const float alpha = min(clamp, o * fast_exp(-0.5f * q));
      const bool use = (alpha >= kAlphaThreshold) & (q >= 0.0f) & (j < last[p]);
      const float inverse = 1.0f / (1.0f - alpha);  // alpha <= clamp < 1
      const float t = use ? T[p] * inverse : T[p];
      const float w = mode == kStandard ? 1.0f : fast_exp(-beta * (1.0f - t));
      const float f = mode == kWabe ? t * w : t;
      const float contrib = use ? alpha * t : 0.0f;
      float d_alpha = f * gc_dot[p] + g_depth[p] * d * t - Q[p] * inverse;
      const float f_prime = mode == kWabe ? w * (1.0f + beta * t) : 1.0f;
      Q[p] += contrib * (f_prime * gc_dot[p] + g_depth[p] * d);
      float cw = use ? alpha * f : 0.0f, dw = contrib;
      if (mode == kWabeGrad) {
        d_alpha *= w;
        cw *= w;
        dw *= w;
      }
      // A clamped alpha does not depend on the Gaussian's opacity or shape.
      const float d_q = (use & (alpha < clamp)) ? -0.5f * alpha * d_alpha : 0.0f;
      T[p] = t;
      colour_weight[p] = cw;
      s_mx += d_q * dx;
      s_my += d_q * dy;
      s_a += d_q * dx * dx;
      s_b += d_q * dx * dy;
      s_c += d_q * dy * dy;
      s_q += d_q;
      s_depth += dw * g_depth[p];
    }
    float* out = grads + (tile * cap + j) * K;
    out[0] = -2.0f * (a * s_mx + b * s_my);
    out[1] = -2.0f * (b * s_mx + c * s_my);
    out[2] = s_a;
    out[3] = 2.0f * s_b;
    out[4] = s_c;
    out[5] = -2.0f * s_q / (o > 0.0f ? o : 1.0f);
    out[6] = s_depth;
    for (int64_t ch = 0; ch < C; ++ch) {
      const float* plane = g_color.data() + ch * kPixels;
      float sum = 0.0f;
#pragma omp simd reduction(+ : sum)
      for (int p = 0; p < kPixels; ++p) sum += colour_weight[p] * plane[p];
      out[kGeometry + ch] = sum;
    }
  }
}

ffi::Error check_inputs(const ffi::Buffer<ffi::S32>& table, const ffi::Buffer<ffi::S32>& kept,
                        const ffi::Buffer<ffi::F32>& packed, int64_t tiles_x) {
  if (table.dimensions().size() != 2 || kept.dimensions().size() != 1 ||
      packed.dimensions().size() != 2)
    return ffi::Error::InvalidArgument(
        "composite kernel: expected table (T, cap), kept (T,), packed (N, K)");
  if (kept.dimensions()[0] != table.dimensions()[0])
    return ffi::Error::InvalidArgument("composite kernel: kept and table disagree on T");
  if (packed.dimensions()[1] <= kGeometry)
    return ffi::Error::InvalidArgument("composite kernel: packed needs 7 + C columns, C >= 1");
  if (tiles_x < 1 || table.dimensions()[0] % tiles_x != 0)
    return ffi::Error::InvalidArgument("composite kernel: T is not a multiple of tiles_x");
  return ffi::Error::Success();
}

Settings settings(const ffi::Buffer<ffi::S32>& table, const ffi::Buffer<ffi::F32>& packed,
                  float alpha_clamp, int32_t mode, float beta, int32_t front,
                  float visibility_beta, int64_t tiles_x) {
  return Settings{alpha_clamp, mode, beta, front, visibility_beta, tiles_x,
                  table.dimensions()[1], packed.dimensions()[1] - kGeometry};
}

ffi::Error Forward(ffi::Buffer<ffi::S32> table, ffi::Buffer<ffi::S32> kept,
                   ffi::Buffer<ffi::F32> packed, ffi::ResultBuffer<ffi::F32> color,
                   ffi::ResultBuffer<ffi::F32> transmittance, ffi::ResultBuffer<ffi::F32> depth,
                   ffi::ResultBuffer<ffi::S32> last, ffi::ResultBuffer<ffi::F32> pixels,
                   ffi::ResultBuffer<ffi::F32> visibility, float alpha_clamp, int32_t mode,
                   float beta, int32_t front_contributors, float visibility_beta, int64_t tiles_x,
                   int32_t threads) {
  if (auto error = check_inputs(table, kept, packed, tiles_x); error.failure()) return error;
  const Settings s = settings(table, packed, alpha_clamp, mode, beta, front_contributors,
                              visibility_beta, tiles_x);
  const ForwardOut out{color->typed_data(), transmittance->typed_data(), depth->typed_data(),
                       last->typed_data(),  pixels->typed_data(),        visibility->typed_data()};
  const int32_t* t = table.typed_data();
  const int32_t* k = kept.typed_data();
  const float* g = packed.typed_data();
  auto walk = s.mode == kWabe ? (front_contributors > 0 ? forward_tile<true, true>
                                                         : forward_tile<true, false>)
                              : (front_contributors > 0 ? forward_tile<false, true>
                                                         : forward_tile<false, false>);
  for_each_tile(table.dimensions()[0], threads,
                [&](int64_t tile) { walk(s, tile, t, k[tile], g, out); });
  return ffi::Error::Success();
}

ffi::Error Backward(ffi::Buffer<ffi::S32> table, ffi::Buffer<ffi::S32> kept,
                    ffi::Buffer<ffi::F32> packed, ffi::Buffer<ffi::F32> t_final,
                    ffi::Buffer<ffi::S32> last, ffi::Buffer<ffi::F32> g_color,
                    ffi::Buffer<ffi::F32> g_transmittance, ffi::Buffer<ffi::F32> g_depth,
                    ffi::ResultBuffer<ffi::F32> grads, float alpha_clamp, int32_t mode,
                    float beta, int64_t tiles_x, int32_t threads) {
  if (auto error = check_inputs(table, kept, packed, tiles_x); error.failure()) return error;
  const Settings s = settings(table, packed, alpha_clamp, mode, beta, 0, 0.0f, tiles_x);
  const BackwardIn in{t_final.typed_data(), last.typed_data(), g_color.typed_data(),
                      g_transmittance.typed_data(), g_depth.typed_data()};
  const int32_t* t = table.typed_data();
  const float* g = packed.typed_data();
  float* out = grads->typed_data();
  auto walk = s.mode == kWabe       ? backward_tile<kWabe>
              : s.mode == kWabeGrad ? backward_tile<kWabeGrad>
                                    : backward_tile<kStandard>;
  for_each_tile(table.dimensions()[0], threads,
                [&](int64_t tile) { walk(s, tile, t, g, in, out); });
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(GaeCompositeForward, Forward,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::S32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Attr<float>("alpha_clamp")
                                  .Attr<int32_t>("mode")
                                  .Attr<float>("beta")
                                  .Attr<int32_t>("front_contributors")
                                  .Attr<float>("visibility_beta")
                                  .Attr<int64_t>("tiles_x")
                                  .Attr<int32_t>("threads"));

XLA_FFI_DEFINE_HANDLER_SYMBOL(GaeCompositeBackward, Backward,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Attr<float>("alpha_clamp")
                                  .Attr<int32_t>("mode")
                                  .Attr<float>("beta")
                                  .Attr<int64_t>("tiles_x")
                                  .Attr<int32_t>("threads"));
