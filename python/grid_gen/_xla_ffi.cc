// grid_gen.jax's XLA FFI handler: one custom call that runs any kernel of any loaded robot
// through the robot library's C ABI batch entry point, on XLA's own buffers (no copy, no
// Python on the call path).
//
// The C ABI (grid-gen's `--backend c`): `int32_t f(size_t n, const T* in..., T* out...)`,
// arrays contiguous, row-major, state-major; 0 is success. The handler is generic: the
// entry point's address comes as the attribute `fn`, the number of inputs is the number of
// operands, and the batch n is the first operand's element count over `state_len` (its
// per-state length), so one compiled handler serves every robot and every kernel. Python
// (grid_gen/jax.py) checks shapes and dtypes before it builds the call; the handler checks
// them again, since a wrong count here would read past a buffer.
//
// XLA FFI's C++ API: https://docs.jax.dev/en/latest/ffi.html (jax.ffi, api_version 1).
#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

// The most pointers a kernel takes (inputs and outputs together): contact_fd_grad with
// fext has 4 inputs and 8 outputs; room to spare.
constexpr std::size_t kMaxPointers = 16;

template <std::size_t... I>
int32_t CallWith(std::intptr_t fn, std::size_t n, void* const* p, std::index_sequence<I...>) {
  using Fn = int32_t (*)(std::size_t, decltype(I, static_cast<void*>(nullptr))...);
  return reinterpret_cast<Fn>(fn)(n, p[I]...);
}

template <std::size_t... K>
int32_t Dispatch(std::intptr_t fn, std::size_t n, void* const* p, std::size_t count,
                 std::index_sequence<K...>) {
  int32_t status = -1000;
  // Exactly one K matches count (checked by the caller to be at most kMaxPointers).
  ((K == count ? (status = CallWith(fn, n, p, std::make_index_sequence<K>{}), 0) : 0), ...);
  return status;
}

ffi::Error Call(int64_t fn, int64_t state_len, int64_t precision_bytes, ffi::RemainingArgs args,
                ffi::RemainingRets rets) {
  if (fn == 0) return ffi::Error::InvalidArgument("grid_gen: null kernel address");
  const std::size_t nin = args.size(), nout = rets.size();
  if (nin == 0 || nout == 0 || nin + nout > kMaxPointers) {
    return ffi::Error::InvalidArgument("grid_gen: unsupported number of operands");
  }
  std::vector<void*> pointers;
  pointers.reserve(nin + nout);
  std::size_t n = 0;
  for (std::size_t i = 0; i < nin; ++i) {
    auto arg = args.get<ffi::AnyBuffer>(i);
    if (arg.has_error()) return arg.error();
    if (ffi::ByteWidth(arg->element_type()) != static_cast<std::size_t>(precision_bytes)) {
      return ffi::Error::InvalidArgument("grid_gen: operand " + std::to_string(i) +
                                         " has the wrong element type");
    }
    if (i == 0) {
      if (state_len <= 0 || arg->element_count() % static_cast<std::size_t>(state_len) != 0) {
        return ffi::Error::InvalidArgument("grid_gen: the first operand's size is not a whole number of states");
      }
      n = arg->element_count() / static_cast<std::size_t>(state_len);
    }
    pointers.push_back(arg->untyped_data());
  }
  for (std::size_t i = 0; i < nout; ++i) {
    auto ret = rets.get<ffi::AnyBuffer>(i);
    if (ret.has_error()) return ret.error();
    if (ffi::ByteWidth((*ret)->element_type()) != static_cast<std::size_t>(precision_bytes)) {
      return ffi::Error::InvalidArgument("grid_gen: result " + std::to_string(i) + " has the wrong element type");
    }
    pointers.push_back((*ret)->untyped_data());
  }
  const int32_t status = Dispatch(static_cast<std::intptr_t>(fn), n, pointers.data(), pointers.size(),
                                  std::make_index_sequence<kMaxPointers + 1>{});
  if (status != 0) {
    return ffi::Error::Internal("grid_gen: the kernel library returned status " + std::to_string(status));
  }
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(GridGenCall, Call,
                              ffi::Ffi::Bind()
                                  .Attr<int64_t>("fn")
                                  .Attr<int64_t>("state_len")
                                  .Attr<int64_t>("precision_bytes")
                                  .RemainingArgs()
                                  .RemainingRets());
