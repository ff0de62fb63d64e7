// libtorch process settings.
#pragma once

#include <string>

namespace at {
class Tensor;
}  // namespace at

namespace soma {

/// "[2, 44, 3]" (or "undefined"), for error messages.
std::string ShapeString(const at::Tensor& tensor);

/// Sets libtorch's intra-op threads (`torch::set_num_threads`, which OpenMP
/// and OpenBLAS-openmp follow) to `num_threads` (<= 0: all hardware threads)
/// and, the first time it is called in the process, the inter-op pool to
/// the same number (`at::set_num_interop_threads` may only be called once,
/// before any inter-op work). libtorch defaults to 1 intra-op thread on the
/// 2-core reference machine (TOOLCHAIN.md), so call this at start-up.
/// Returns the intra-op thread count in effect.
int SetTorchThreads(int num_threads);

/// The current intra-op thread count (`at::get_num_threads()`).
int TorchThreads();

}  // namespace soma
