// Tile lists on CPU, called from JAX through the XLA FFI (gae_jax.render.cpu_kernel.bin_tiles).
//
// The lists tiles.bin_gaussians builds with a budget-sized key sort, scatters and gathers, by one
// walk over the Gaussians in depth order: pair p (counted over Gaussians by rank, each one's
// tiles row-major over its rectangle) is dropped when p >= budget; a tile appends the Gaussian
// while it holds fewer than `capacity`. Each tile's list is therefore in rank order and keeps
// its nearest `capacity` pairs of the budget, exactly as the sort does. O(N + pairs), one thread:
// at 50k Gaussians the walk takes well under a millisecond.
//
// Inputs (N,) int32: x0, x1, y0, y1 (inclusive tile ranges, x1 < x0 or y1 < y0 = no tile) and
// order (the depth order, a permutation of 0..N-1). Outputs: table (T, capacity) int32 (-1
// padding) and pairs (T,) int32, the pairs of the budget that fell on each tile (before the
// capacity; the caller takes min(pairs, capacity) as the kept count).

#include <algorithm>
#include <cstdint>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

ffi::Error BinTiles(ffi::Buffer<ffi::S32> x0, ffi::Buffer<ffi::S32> x1,
                    ffi::Buffer<ffi::S32> y0, ffi::Buffer<ffi::S32> y1,
                    ffi::Buffer<ffi::S32> order, int64_t tiles_x, int64_t budget,
                    ffi::ResultBuffer<ffi::S32> table, ffi::ResultBuffer<ffi::S32> pairs) {
  const int64_t n = order.dimensions()[0];
  const auto table_dims = table->dimensions();
  if (table_dims.size() != 2 || x0.dimensions()[0] != n || x1.dimensions()[0] != n ||
      y0.dimensions()[0] != n || y1.dimensions()[0] != n || tiles_x < 1)
    return ffi::Error::InvalidArgument("bin kernel: expected (N,) ranges and a (T, cap) table");
  const int64_t num_tiles = table_dims[0], capacity = table_dims[1];
  int32_t* out = table->typed_data();
  int32_t* count = pairs->typed_data();
  std::fill(out, out + num_tiles * capacity, -1);
  std::fill(count, count + num_tiles, 0);
  const int32_t *gx0 = x0.typed_data(), *gx1 = x1.typed_data();
  const int32_t *gy0 = y0.typed_data(), *gy1 = y1.typed_data(), *rank = order.typed_data();
  int64_t p = 0;
  for (int64_t r = 0; r < n && p < budget; ++r) {
    const int32_t g = rank[r];
    if (g < 0 || g >= n)
      return ffi::Error::InvalidArgument("bin kernel: order is not a permutation of 0..N-1");
    if (gx1[g] < gx0[g] || gy1[g] < gy0[g]) continue;
    for (int64_t ty = gy0[g]; ty <= gy1[g] && p < budget; ++ty) {
      for (int64_t tx = gx0[g]; tx <= gx1[g] && p < budget; ++tx, ++p) {
        const int64_t t = ty * tiles_x + tx;
        if (t < 0 || t >= num_tiles)
          return ffi::Error::InvalidArgument("bin kernel: a tile range lies outside the grid");
        if (count[t] < capacity) out[t * capacity + count[t]] = g;
        ++count[t];
      }
    }
  }
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(GaeBinTiles, BinTiles,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Attr<int64_t>("tiles_x")
                                  .Attr<int64_t>("budget")
                                  .Ret<ffi::Buffer<ffi::S32>>()
                                  .Ret<ffi::Buffer<ffi::S32>>());
