// CPU compositor of tile lists, called from JAX through the XLA FFI (gae_jax.render.cpu_kernel).
//
// The same numerics as gae_jax/render/composite.py (its docstrings define them): per pixel, the
// tile's list is walked nearest first; q = [dx dy] conic [dx dy]^T, alpha = min(clamp, o
// exp(-q/2)), skipped when alpha < 1/255 or q < 0; a pixel stops before the slot that would take
// its transmittance under 1e-4. The backward walks each list back to front as the reference CUDA
// backward does (T recovered as T_{j+1} / (1 - a_j), a slot counts iff it lies before the pixel's
// last composited slot). Per-slot results are written per tile; the Python side scatters them to
// Gaussians, so tiles are independent and run on worker threads. Within a tile the 256 pixels
// are the SIMD lanes (struct-of-arrays state, branch-free selects, a polynomial exp), and each
// Gaussian is evaluated only on the rows of the tile its alpha can reach (`reach`).
//
// Layouts (row-major): table (T, cap) int32, -1 padding; kept (T,) int32; packed (N, 7 + C)
// float32 = mean x, mean y, conic a, b, c, opacity, depth, colour; per-pixel arrays (T, 256[, C])
// in the per-tile layout of composite.pixel_centres.

#include <algorithm>
#include <atomic>
#include <chrono>
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

// The pixels of a tile that a Gaussian can give alpha >= 1/255, as a range [begin, end) of the
// tile's row-major pixels (whole rows). o exp(-q/2) >= 1/255 needs q <= Q = 2 ln(255 o), and on
// the ellipse q = Q, |y - my| reaches at most sqrt(Q Sigma_yy) with Sigma_yy = a / (a c - b^2)
// (the conic is Sigma's inverse): rows farther away hold only pixels the walk would skip, so
// leaving them out changes no output. One row of margin covers rounding; a conic that is not
// positive definite (q can be negative there) keeps every row.
struct Span {
  int begin, end;
};

Span reach(float oy, float my, float a, float b, float c, float o) {
  const float det = a * c - b * b;
  if (!(det > 0.0f) || !(a > 0.0f)) return {0, kPixels};
  if (!(o * 255.0f > 1.0f)) return {0, 0};
  const float half = std::sqrt(2.0f * std::log(255.0f * o) * a / det);
  if (!(half < static_cast<float>(kTile))) return {0, kPixels};
  const float low = my - half - oy - 0.5f, high = my + half - oy - 0.5f;
  const int first = std::max(0, static_cast<int>(std::floor(low)) - 1);
  const int last = std::min(kTile - 1, static_cast<int>(std::ceil(high)) + 1);
  if (first > last) return {0, 0};
  return {first * kTile, (last + 1) * kTile};
}

// One tile row of floats as a vector (GCC / Clang vector extension). Partial sums over a span's
// rows are kept in these so that they stay in registers: as arrays indexed by lane, or as
// `omp simd` reductions over a loop whose trip count is not a constant, gcc keeps them in
// memory, and the backward walk ran ~1.5x slower over fewer pixels.
typedef float Row __attribute__((vector_size(kTile * sizeof(float))));

inline Row load_row(const float* x) {
  Row v;
  std::memcpy(&v, x, sizeof(v));
  return v;
}

inline float sum_row(const Row& v) {
  float sum = 0.0f;
  for (int lane = 0; lane < kTile; ++lane) sum += v[lane];
  return sum;
}

// sum over the span of x[p] y[p].
inline float span_dot(const float* x, const float* y, Span span) {
  Row sum = {};
  for (int row = span.begin; row < span.end; row += kTile)
    sum += load_row(x + row) * load_row(y + row);
  return sum_row(sum);
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
  alignas(64) int32_t done[kPixels], last[kPixels], seen[kPixels], fresh[kPixels];
  alignas(64) float vis[kPixels];
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
  const float oy = static_cast<float>((tile / s.tiles_x) * kTile);
  int32_t finished = 0;
  for (int32_t j = 0; j < kept; ++j) {
    const int32_t index = table[tile * cap + j];
    if (index < 0) continue;
    const float* g = packed + static_cast<int64_t>(index) * K;
    const float mx = g[0], my = g[1], a = g[2], b = g[3], c = g[4], o = g[5], d = g[6];
    const Span span = reach(oy, my, a, b, c, o);
    // No reductions in the heavy loop: gcc's `omp simd` reductions cost more than the loop's
    // arithmetic once the trip count is not a constant; the counts are taken after it.
#pragma omp simd
    for (int p = span.begin; p < span.end; ++p) {
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
        vis[p] = first ? fast_exp(-s.visibility_beta * (1.0f - t)) * alpha : 0.0f;
        seen[p] += use ? 1 : 0;
      }
      fresh[p] = stop ? 1 : 0;
      done[p] = (done[p] != 0) | stop;
      T[p] = use ? t_next : t;
    }
    int32_t used = 0, stopped = 0;
    for (int p = span.begin; p < span.end; ++p) {
      used += last[p] == j + 1 ? 1 : 0;
      stopped += fresh[p];
    }
    float vis_max = 0.0f;
    if (kFront) {
#pragma omp simd reduction(max : vis_max)
      for (int p = span.begin; p < span.end; ++p) vis_max = max(vis_max, vis[p]);
    }
    for (int64_t ch = 0; ch < C; ++ch) {
      const float value = g[kGeometry + ch];
      float* plane = color.data() + ch * kPixels;
#pragma omp simd
      for (int p = span.begin; p < span.end; ++p) plane[p] += weight[p] * value;
    }
    pixels[j] = static_cast<float>(used);
    visibility[j] = vis_max;
    finished += stopped;
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
  alignas(64) float gc_dot[kPixels], colour_weight[kPixels], d_q[kPixels], d_depth[kPixels];
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
  const float oy = static_cast<float>((tile / s.tiles_x) * kTile);
  for (int32_t j = top - 1; j >= 0; --j) {
    const int32_t index = table[tile * cap + j];
    if (index < 0) continue;
    const float* g = packed + static_cast<int64_t>(index) * K;
    const float mx = g[0], my = g[1], a = g[2], b = g[3], c = g[4], o = g[5], d = g[6];
    // Outside the span no pixel uses this slot: its terms there are zero and T, Q unchanged.
    const Span span = reach(oy, my, a, b, c, o);
    for (int64_t ch = 0; ch < C; ++ch) {
      const float value = g[kGeometry + ch];
      const float* plane = g_color.data() + ch * kPixels;
      if (ch == 0) {
#pragma omp simd
        for (int p = span.begin; p < span.end; ++p) gc_dot[p] = plane[p] * value;
      } else {
#pragma omp simd
        for (int p = span.begin; p < span.end; ++p) gc_dot[p] += plane[p] * value;
      }
    }
#pragma omp simd
    for (int p = span.begin; p < span.end; ++p) {
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
      d_q[p] = (use & (alpha < clamp)) ? -0.5f * alpha * d_alpha : 0.0f;
      d_depth[p] = dw * g_depth[p];
      T[p] = t;
      colour_weight[p] = cw;
    }
    // The per-slot sums, a row of partial sums each (held in registers: see `Row`).
    Row s_mx_ = {}, s_my_ = {}, s_a_ = {}, s_b_ = {}, s_c_ = {}, s_q_ = {}, s_depth_ = {};
    for (int row = span.begin; row < span.end; row += kTile) {
      const Row dx = load_row(px + row) - mx, dy = load_row(py + row) - my;
      const Row g_q = load_row(d_q + row);
      s_mx_ += g_q * dx;
      s_my_ += g_q * dy;
      s_a_ += g_q * dx * dx;
      s_b_ += g_q * dx * dy;
      s_c_ += g_q * dy * dy;
      s_q_ += g_q;
      s_depth_ += load_row(d_depth + row);
    }
    const float s_mx = sum_row(s_mx_), s_my = sum_row(s_my_), s_a = sum_row(s_a_),
                s_b = sum_row(s_b_), s_c = sum_row(s_c_), s_q = sum_row(s_q_),
                s_depth = sum_row(s_depth_);
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
      out[kGeometry + ch] = span_dot(colour_weight, plane, span);
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

namespace {

// One thread's share of GaeExpRate: `rounds` passes of fast_exp over a tile's worth of lanes
// held in registers / L1, as the compositor's pixel loop runs it. The argument moves with the
// round, so no pass can be hoisted; the sum keeps the results alive.
float exp_rounds(int64_t rounds) {
  alignas(64) float x[kPixels], acc[kPixels];
  for (int p = 0; p < kPixels; ++p) {
    x[p] = -10.0f * static_cast<float>(p) / kPixels;
    acc[p] = 0.0f;
  }
  for (int64_t r = 0; r < rounds; ++r) {
    const float shift = static_cast<float>(r & 1023) * 1e-4f;
#pragma omp simd
    for (int p = 0; p < kPixels; ++p) acc[p] += fast_exp(x[p] - shift);
  }
  float sum = 0.0f;
  for (int p = 0; p < kPixels; ++p) sum += acc[p];
  return sum;
}

}  // namespace

// The machine's rate of the compositor's own exp: fast_exp evaluations per second on `threads`
// workers (0: one per hardware thread), each running `rounds` x 256 of them; *checksum receives
// their sum (so that nothing is optimised away). The compositor needs at least one exp per
// (pixel, Gaussian) pair it evaluates, so this rate bounds its pairs per second.
extern "C" double GaeExpRate(int32_t threads, int64_t rounds, float* checksum) {
  int64_t workers = threads > 0 ? threads : std::max(1u, std::thread::hardware_concurrency());
  std::vector<float> sums(workers, 0.0f);
  const auto start = std::chrono::steady_clock::now();
  std::vector<std::thread> pool;
  for (int64_t i = 1; i < workers; ++i)
    pool.emplace_back([&sums, i, rounds]() { sums[i] = exp_rounds(rounds); });
  sums[0] = exp_rounds(rounds);
  for (auto& t : pool) t.join();
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  float total = 0.0f;
  for (float s : sums) total += s;
  *checksum = total;
  return static_cast<double>(workers) * static_cast<double>(rounds) * kPixels / seconds;
}
