// NumPy .npy reader and writer.
//
// .npy (NumPy NEP 1, "A Simple File Format for NumPy Arrays"): the magic
// "\x93NUMPY", a version byte pair (1.0: 2-byte little-endian header length;
// 2.0 and 3.0: 4-byte; 3.0 allows UTF-8 in the header), then an ASCII Python
// dict literal {'descr': '<f8', 'fortran_order': False, 'shape': (3, 4), }
// padded with spaces and ended by '\n', then the raw array bytes.
//
// Supported dtypes (descr): booleans '|b1'; integers '|i1' '|u1' '<i2' '<u2'
// '<i4' '<u4' '<i8' '<u8'; floats '<f4' '<f8'; fixed-width strings '<U<n>'
// (UCS-4) and '|S<n>' (bytes). Big-endian ('>') descriptors are converted to
// little-endian on reading. Object arrays ('O', pickled) and structured
// dtypes are rejected with an IoError naming the entry.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// One n-dimensional NumPy array: normalised dtype, shape, memory order and
/// the raw element bytes (little-endian, `num_elements() * item_size()`
/// bytes, in `fortran_order` if set).
struct NpyArray {
  /// Normalised descriptor: '<' for multi-byte numbers and '<U', '|' for
  /// one-byte types and '|S'. E.g. "<f8", "<i4", "|u1", "|b1", "<U6", "|S3".
  std::string dtype = "<f8";
  std::vector<int64_t> shape;  // empty = 0-d scalar (one element)
  bool fortran_order = false;
  std::vector<uint8_t> data;

  /// Product of the shape (1 for a 0-d array).
  int64_t num_elements() const;
  /// Bytes per element (8 for "<f8", 4 * n for "<U<n>").
  int item_size() const;
  /// dtype kind: 'b' bool, 'i' signed, 'u' unsigned, 'f' float, 'U', 'S'.
  char kind() const;
  int ndim() const { return static_cast<int>(shape.size()); }
  /// Shape as Python prints it: "(3, 4)", "(5,)", "()".
  std::string ShapeString() const;

  /// Elements as doubles in C (row-major) order whatever `fortran_order`
  /// is. Numeric and bool dtypes; IoError for strings. 64-bit integers
  /// beyond 2^53 lose precision.
  std::vector<double> AsDoubles() const;
  /// Elements as int64 in C order. Integer and bool dtypes, and floats
  /// holding integral values; IoError otherwise (and for uint64 > 2^63-1).
  std::vector<int64_t> AsInt64() const;
  /// Elements of a '<U' / '|S' array in C order, trailing NULs removed
  /// (UCS-4 is converted to UTF-8).
  std::vector<std::string> AsStrings() const;
  /// A 0-d, 1-d (n x 1) or 2-d array as a dense matrix; ShapeError for
  /// ndim > 2.
  Eigen::MatrixXd AsMatrix() const;

  // Builders (C order). Each throws ShapeError if the value count does not
  // match the shape.
  static NpyArray FromDoubles(std::vector<int64_t> shape,
                              const std::vector<double>& values);
  static NpyArray FromFloats(std::vector<int64_t> shape,
                             const std::vector<float>& values);
  static NpyArray FromInt64(std::vector<int64_t> shape,
                            const std::vector<int64_t>& values);
  static NpyArray FromInt32(std::vector<int64_t> shape,
                            const std::vector<int32_t>& values);
  static NpyArray FromUInt32(std::vector<int64_t> shape,
                             const std::vector<uint32_t>& values);
  static NpyArray FromUInt8(std::vector<int64_t> shape,
                            const std::vector<uint8_t>& values);
  static NpyArray FromBools(std::vector<int64_t> shape,
                            const std::vector<bool>& values);
  /// '<U<n>' with n the longest string (in code points, at least 1).
  static NpyArray FromStrings(std::vector<int64_t> shape,
                              const std::vector<std::string>& values);
  /// A 2-d '<f8' array (rows x cols, C order).
  static NpyArray FromMatrix(const Eigen::MatrixXd& matrix);
};

/// Parses one .npy image. `source` names it in errors (e.g. "a.npz: entry
/// 'x.npy'"). Throws IoError on a bad magic, version, header, unsupported
/// dtype or a data size that does not match the shape.
NpyArray ParseNpy(std::string_view bytes, std::string_view source);

/// Serialises an array as .npy (version 1.0, or 2.0 when the header exceeds
/// 65535 bytes; header padded to a multiple of 64 bytes). Throws ShapeError
/// if `data` does not hold num_elements() * item_size() bytes.
std::string SerializeNpy(const NpyArray& array);

/// Reads a single .npy file.
NpyArray ReadNpy(const std::filesystem::path& path);
/// Writes a single .npy file atomically.
void WriteNpy(const std::filesystem::path& path, const NpyArray& array);

}  // namespace soma
