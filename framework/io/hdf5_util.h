// HDF5 C-API plumbing shared by the modules that read and write HDF5 files
// (io/mocap_dataset.cc, synth/noise_bank.cc): the process-wide HDF5 lock, an
// RAII owner of HDF5 identifiers, error checks that throw IoError, and
// scalar / string / string-array attribute readers and writers.
// Hand-written on libhdf5's C API because Debian 12 packages no C++ wrapper
// for it (HighFive, h5cpp are not in it).
//
// Internal to modules that link HDF5::HDF5 (this header includes <hdf5.h>);
// not part of the public API and not re-exported by soma_io's headers.
//
// Thread safety: Debian's libhdf5 is the serial build, which is NOT
// thread-safe. Every HDF5 call in the process, including the close in ~Hid(),
// must happen while holding Hdf5Mutex(). The helpers below take the lock
// themselves (it is recursive), but a caller doing a sequence of calls must
// hold it across the whole sequence.
#pragma once

// Modules linking HDF5::HDF5 have <hdf5.h> on their include path; a test that
// only gets HDF5 through soma_io's link line finds Debian's serial headers.
#if __has_include(<hdf5.h>)
#include <hdf5.h>
#else
#include <hdf5/serial/hdf5.h>
#endif

#include <cstdint>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

namespace soma::hdf5 {

/// The one lock serialising every HDF5 call in the process. The first call
/// also switches off HDF5's automatic error-stack printing (failures become
/// IoErrors instead).
std::recursive_mutex& Hdf5Mutex();

/// Owns one HDF5 identifier and closes it with `closer` (H5Fclose, H5Dclose,
/// ...). Move-only. Destroy it while holding Hdf5Mutex().
class Hid {
 public:
  using Closer = herr_t (*)(hid_t);
  Hid() = default;
  Hid(hid_t id, Closer closer) : id_(id), closer_(closer) {}
  Hid(const Hid&) = delete;
  Hid& operator=(const Hid&) = delete;
  Hid(Hid&& other) noexcept { *this = std::move(other); }
  Hid& operator=(Hid&& other) noexcept {
    if (this != &other) {
      Reset();
      id_ = std::exchange(other.id_, H5I_INVALID_HID);
      closer_ = other.closer_;
    }
    return *this;
  }
  ~Hid() { Reset(); }

  hid_t get() const { return id_; }
  bool valid() const { return id_ >= 0; }
  /// Closes now; returns false if HDF5 reported an error.
  bool Reset() {
    bool ok = true;
    if (id_ >= 0 && closer_ != nullptr) ok = closer_(id_) >= 0;
    id_ = H5I_INVALID_HID;
    return ok;
  }

 private:
  hid_t id_ = H5I_INVALID_HID;
  Closer closer_ = nullptr;
};

/// Wraps `id` in a Hid; IoError(what) if it is negative (HDF5 failure).
Hid Check(hid_t id, Hid::Closer closer, const std::string& what);

/// IoError(what) if `status` is negative (HDF5 failure).
void CheckStatus(herr_t status, const std::string& what);

/// A variable-length UTF-8 string type (what h5py writes for `str`).
Hid VlenStringType();

/// The prefix of schema errors: "<file>: not a valid <format>: ", e.g.
/// "a.h5: not a valid soma dataset: ". The attribute readers take it as `bad`.
std::string InvalidFilePrefix(const std::string& file,
                              const std::string& format);

/// Memory (native) and file (little-endian) HDF5 types of a number type.
template <typename T>
struct NumberType;
template <>
struct NumberType<int32_t> {
  static hid_t Memory() { return H5T_NATIVE_INT32; }
  static hid_t File() { return H5T_STD_I32LE; }
};
template <>
struct NumberType<int64_t> {
  static hid_t Memory() { return H5T_NATIVE_INT64; }
  static hid_t File() { return H5T_STD_I64LE; }
};
template <>
struct NumberType<uint64_t> {
  static hid_t Memory() { return H5T_NATIVE_UINT64; }
  static hid_t File() { return H5T_STD_U64LE; }
};
template <>
struct NumberType<float> {
  static hid_t Memory() { return H5T_NATIVE_FLOAT; }
  static hid_t File() { return H5T_IEEE_F32LE; }
};
template <>
struct NumberType<double> {
  static hid_t Memory() { return H5T_NATIVE_DOUBLE; }
  static hid_t File() { return H5T_IEEE_F64LE; }
};

// ---- Writing attributes. `file` names the file in error messages
// ("<file>: cannot create attribute '<name>'", "... cannot write ...").

/// Writes the scalar attribute `name` of `object` (a file, group or dataset),
/// replacing an existing one: `value` points to one `mem_type` element stored
/// as `file_type`.
void WriteAttribute(hid_t object,
                    const char* name,
                    hid_t mem_type,
                    hid_t file_type,
                    const void* value,
                    const std::string& file);

/// Writes a scalar variable-length UTF-8 string attribute.
void WriteStringAttribute(hid_t object,
                          const std::string& name,
                          const std::string& value,
                          const std::string& file);

/// Writes a 1-D array of variable-length UTF-8 strings (h5py reads a numpy
/// object array).
void WriteStringArrayAttribute(hid_t object,
                               const char* name,
                               const std::vector<std::string>& values,
                               const std::string& file);

/// Writes a scalar number attribute, stored little-endian (NumberType<T>).
template <typename T>
void WriteNumberAttribute(hid_t object,
                          const char* name,
                          T value,
                          const std::string& file) {
  WriteAttribute(object,
                 name,
                 NumberType<T>::Memory(),
                 NumberType<T>::File(),
                 &value,
                 file);
}

// ---- Reading attributes. Every error is an IoError `bad` + detail, with
// `bad` from InvalidFilePrefix (so it names the file) and the detail naming
// the attribute: "missing attribute 'x'", "attribute 'x' is not a string".

/// Opens attribute `name` of `object`; IoError if it is missing.
Hid OpenAttribute(hid_t object, const char* name, const std::string& bad);

/// Reads an open scalar or 1-D string attribute `attr` (called `name` in
/// messages), fixed or variable length.
std::vector<std::string> ReadStrings(hid_t attr,
                                     const std::string& name,
                                     const std::string& bad);

/// Reads a string attribute holding exactly one string.
std::string ReadStringAttribute(hid_t object,
                                const char* name,
                                const std::string& bad);

/// Reads a scalar or 1-D string-array attribute.
std::vector<std::string> ReadStringArrayAttribute(hid_t object,
                                                  const char* name,
                                                  const std::string& bad);

/// Reads a scalar integer or float attribute into an `mem_type` value
/// (`value` points to one element); HDF5 converts the number.
void ReadNumberAttribute(hid_t object,
                         const char* name,
                         hid_t mem_type,
                         void* value,
                         const std::string& bad);

/// Reads a scalar number attribute converted to T (int32_t, int64_t, ...).
template <typename T>
T ReadNumberAttribute(hid_t object, const char* name, const std::string& bad) {
  T value{};
  ReadNumberAttribute(object, name, NumberType<T>::Memory(), &value, bad);
  return value;
}

// ---- Opening a soma file.

/// Opens `path` read-only as a `what` file (e.g. "soma solve output") whose
/// root attribute `format` must equal `format` and, when `version` > 0,
/// `format_version` must equal `version`. IoError naming the file for a
/// missing file, not HDF5, a missing or other format or version. `*bad`
/// gets InvalidFilePrefix(path, what) for the caller's own errors. The
/// caller holds Hdf5Mutex() while it uses the file.
Hid OpenFormattedFile(const std::string& path,
                      const std::string& what,
                      const std::string& format,
                      int version,
                      std::string* bad);

// ---- Numeric datasets. Errors name the file (`file` / `bad`) and dataset.

/// Creates dataset `name` of `object` with shape `dims` (row-major) and
/// writes `values` (`count` = prod(dims) elements of `mem_type`, else
/// InternalError) stored as `file_type`.
void WriteDataset(hid_t object,
                  const char* name,
                  const std::vector<hsize_t>& dims,
                  hid_t mem_type,
                  hid_t file_type,
                  const void* values,
                  size_t count,
                  const std::string& file);

template <typename T>
void WriteDataset(hid_t object,
                  const char* name,
                  const std::vector<hsize_t>& dims,
                  const std::vector<T>& values,
                  const std::string& file) {
  WriteDataset(object,
               name,
               dims,
               NumberType<T>::Memory(),
               NumberType<T>::File(),
               values.data(),
               values.size(),
               file);
}

/// The shape of dataset `name` of `object`; IoError `bad` + "missing
/// dataset '<name>'" if absent.
std::vector<hsize_t> DatasetShape(hid_t object,
                                  const char* name,
                                  const std::string& bad);

/// Reads numeric dataset `name` converted to T (HDF5 converts the number
/// type). If `expected_dims` is not empty, its non-zero entries must match
/// the dataset's shape (0 = any size) or IoError names both shapes.
/// `dims` (optional) gets the shape read.
template <typename T>
std::vector<T> ReadDataset(hid_t object,
                           const char* name,
                           const std::vector<hsize_t>& expected_dims,
                           const std::string& bad,
                           std::vector<hsize_t>* dims = nullptr);

}  // namespace soma::hdf5
