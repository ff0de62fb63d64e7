#include "framework/model/torch_utils.h"

#include <ATen/Parallel.h>
#include <ATen/core/Tensor.h>
#include <fmt/format.h>

#include <algorithm>
#include <exception>
#include <mutex>
#include <thread>

namespace soma {

int SetTorchThreads(int num_threads) {
  if (num_threads <= 0) {
    num_threads =
        static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  }
  static std::once_flag interop_once;
  std::call_once(interop_once, [num_threads] {
    // Throws if inter-op work already ran; the intra-op setting below is what
    // matters for a forward pass, so a late call only keeps torch's default.
    try {
      at::set_num_interop_threads(num_threads);
    } catch (const std::exception&) {
    }
  });
  at::set_num_threads(num_threads);
  return at::get_num_threads();
}

std::string ShapeString(const at::Tensor& tensor) {
  if (!tensor.defined()) return "undefined";
  return fmt::format("[{}]", fmt::join(tensor.sizes(), ", "));
}

int TorchThreads() { return at::get_num_threads(); }

}  // namespace soma
