// Stable argsort of int32 keys on CPU, called from JAX through the XLA FFI
// (gae_jax.render.cpu_kernel.argsort). XLA:CPU's two-operand stable sort takes ~20 ms for the
// 50k-Gaussian depth order of tiles.depth_order, more than the whole compositor walk. Here
// (key, index) is packed in one 64-bit integer and sorted by a least-significant-digit radix
// sort on the key's four bytes: each pass is stable and the input is in index order, so ties
// stay in index order, the permutation of the stable sort. A byte that every key shares is
// skipped. 0.3-0.5 ms at 50k against ~2.5 ms for std::sort of the packed integers.

#include <algorithm>
#include <cstdint>
#include <vector>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

ffi::Error Argsort(ffi::Buffer<ffi::S32> keys, ffi::ResultBuffer<ffi::S32> order) {
  if (keys.dimensions().size() != 1)
    return ffi::Error::InvalidArgument("argsort kernel: expected keys of shape (N,)");
  const int64_t n = keys.dimensions()[0];
  const int32_t* key = keys.typed_data();
  std::vector<uint64_t> packed(n);
  for (int64_t i = 0; i < n; ++i) {
    // Flipping the sign bit orders signed keys as unsigned ones; the index breaks ties.
    const uint32_t k = static_cast<uint32_t>(key[i]) ^ 0x80000000u;
    packed[i] = (static_cast<uint64_t>(k) << 32) | static_cast<uint32_t>(i);
  }
  std::vector<uint64_t> spare(n);
  for (int shift = 32; shift < 64; shift += 8) {
    int64_t start[257] = {0};
    for (int64_t i = 0; i < n; ++i) ++start[((packed[i] >> shift) & 0xffu) + 1];
    if (std::find(start + 1, start + 257, n) != start + 257) continue;  // one digit for all
    for (int d = 0; d < 256; ++d) start[d + 1] += start[d];
    for (int64_t i = 0; i < n; ++i) spare[start[(packed[i] >> shift) & 0xffu]++] = packed[i];
    packed.swap(spare);
  }
  int32_t* out = order->typed_data();
  for (int64_t i = 0; i < n; ++i) out[i] = static_cast<int32_t>(packed[i] & 0xffffffffu);
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(GaeArgsortInt32, Argsort,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Ret<ffi::Buffer<ffi::S32>>());
