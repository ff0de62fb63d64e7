// Little-endian integer reads and appends shared by the binary formats of
// the io module (.npy headers, zip records). Internal to the io module.
#pragma once

#include <bit>
#include <cstdint>
#include <cstring>
#include <string>

namespace soma {
namespace internal {

static_assert(std::endian::native == std::endian::little,
              "the io module assumes a little-endian host (NpyArray::data and "
              "zip records are little-endian)");

/// The little-endian integer at `p` (no alignment needed).
inline uint16_t Le16(const char* p) {
  uint16_t v;
  std::memcpy(&v, p, 2);
  return v;
}
inline uint32_t Le32(const char* p) {
  uint32_t v;
  std::memcpy(&v, p, 4);
  return v;
}
inline uint64_t Le64(const char* p) {
  uint64_t v;
  std::memcpy(&v, p, 8);
  return v;
}

/// Appends `v` to `out` in little-endian byte order.
inline void Put16(std::string& out, uint16_t v) {
  out.append(reinterpret_cast<const char*>(&v), 2);
}
inline void Put32(std::string& out, uint32_t v) {
  out.append(reinterpret_cast<const char*>(&v), 4);
}
inline void Put64(std::string& out, uint64_t v) {
  out.append(reinterpret_cast<const char*>(&v), 8);
}

}  // namespace internal
}  // namespace soma
