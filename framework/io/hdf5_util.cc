#include "framework/io/hdf5_util.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <cstring>
#include <filesystem>

namespace soma::hdf5 {

std::recursive_mutex& Hdf5Mutex() {
  static std::recursive_mutex mutex;
  static std::once_flag once;
  std::call_once(once, [] { H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr); });
  return mutex;
}

Hid Check(hid_t id, Hid::Closer closer, const std::string& what) {
  if (id < 0) throw IoError(what);
  return Hid(id, closer);
}

void CheckStatus(herr_t status, const std::string& what) {
  if (status < 0) throw IoError(what);
}

Hid VlenStringType() {
  std::lock_guard lock(Hdf5Mutex());
  Hid type = Check(H5Tcopy(H5T_C_S1), H5Tclose, "H5Tcopy failed");
  CheckStatus(H5Tset_size(type.get(), H5T_VARIABLE), "H5Tset_size failed");
  CheckStatus(H5Tset_cset(type.get(), H5T_CSET_UTF8), "H5Tset_cset failed");
  return type;
}

std::string InvalidFilePrefix(const std::string& file,
                              const std::string& format) {
  return fmt::format("{}: not a valid {}: ", file, format);
}

// ---- Writing attributes.

void WriteAttribute(hid_t object,
                    const char* name,
                    hid_t mem_type,
                    hid_t file_type,
                    const void* value,
                    const std::string& file) {
  std::lock_guard lock(Hdf5Mutex());
  const Hid space = Check(H5Screate(H5S_SCALAR), H5Sclose, file);
  if (H5Aexists(object, name) > 0) H5Adelete(object, name);
  const Hid attr =
      Check(H5Acreate2(
                object, name, file_type, space.get(), H5P_DEFAULT, H5P_DEFAULT),
            H5Aclose,
            fmt::format("{}: cannot create attribute '{}'", file, name));
  CheckStatus(H5Awrite(attr.get(), mem_type, value),
              fmt::format("{}: cannot write attribute '{}'", file, name));
}

void WriteStringAttribute(hid_t object,
                          const std::string& name,
                          const std::string& value,
                          const std::string& file) {
  std::lock_guard lock(Hdf5Mutex());
  const Hid type = VlenStringType();
  const char* data = value.c_str();
  WriteAttribute(object, name.c_str(), type.get(), type.get(), &data, file);
}

void WriteStringArrayAttribute(hid_t object,
                               const char* name,
                               const std::vector<std::string>& values,
                               const std::string& file) {
  std::lock_guard lock(Hdf5Mutex());
  const Hid type = VlenStringType();
  const hsize_t dims[1] = {values.size()};
  const Hid space = Check(H5Screate_simple(1, dims, nullptr), H5Sclose, file);
  if (H5Aexists(object, name) > 0) H5Adelete(object, name);
  const Hid attr = Check(
      H5Acreate2(
          object, name, type.get(), space.get(), H5P_DEFAULT, H5P_DEFAULT),
      H5Aclose,
      fmt::format("{}: cannot create attribute '{}'", file, name));
  std::vector<const char*> pointers;
  pointers.reserve(values.size());
  for (const std::string& value : values) pointers.push_back(value.c_str());
  if (!values.empty()) {
    CheckStatus(H5Awrite(attr.get(), type.get(), pointers.data()),
                fmt::format("{}: cannot write attribute '{}'", file, name));
  }
}

// ---- Reading attributes.

Hid OpenAttribute(hid_t object, const char* name, const std::string& bad) {
  std::lock_guard lock(Hdf5Mutex());
  if (H5Aexists(object, name) <= 0) {
    throw IoError(bad + fmt::format("missing attribute '{}'", name));
  }
  return Check(H5Aopen(object, name, H5P_DEFAULT),
               H5Aclose,
               bad + fmt::format("cannot open attribute '{}'", name));
}

std::vector<std::string> ReadStrings(hid_t attr,
                                     const std::string& name,
                                     const std::string& bad) {
  std::lock_guard lock(Hdf5Mutex());
  const std::string cannot_read =
      bad + fmt::format("cannot read attribute '{}'", name);
  const Hid type = Check(H5Aget_type(attr), H5Tclose, cannot_read);
  if (H5Tget_class(type.get()) != H5T_STRING) {
    throw IoError(bad + fmt::format("attribute '{}' is not a string", name));
  }
  const Hid space = Check(H5Aget_space(attr), H5Sclose, cannot_read);
  const int rank = H5Sget_simple_extent_ndims(space.get());
  if (rank > 1 || rank < 0) {
    throw IoError(bad + fmt::format("attribute '{}' has rank {}, expected a "
                                    "scalar or 1-D string array",
                                    name,
                                    rank));
  }
  const hssize_t count = H5Sget_simple_extent_npoints(space.get());
  std::vector<std::string> values;
  if (count <= 0) return values;
  if (H5Tis_variable_str(type.get()) > 0) {
    const Hid mem = VlenStringType();
    H5Tset_cset(mem.get(), H5Tget_cset(type.get()));
    std::vector<char*> pointers(static_cast<size_t>(count), nullptr);
    CheckStatus(H5Aread(attr, mem.get(), pointers.data()), cannot_read);
    for (char* p : pointers) values.emplace_back(p == nullptr ? "" : p);
    H5Dvlen_reclaim(mem.get(), space.get(), H5P_DEFAULT, pointers.data());
  } else {
    const size_t size = H5Tget_size(type.get());
    std::vector<char> buffer(size * static_cast<size_t>(count));
    CheckStatus(H5Aread(attr, type.get(), buffer.data()), cannot_read);
    for (hssize_t i = 0; i < count; ++i) {
      const char* begin = buffer.data() + i * size;
      values.emplace_back(begin, strnlen(begin, size));
    }
  }
  return values;
}

std::string ReadStringAttribute(hid_t object,
                                const char* name,
                                const std::string& bad) {
  std::lock_guard lock(Hdf5Mutex());
  const Hid attr = OpenAttribute(object, name, bad);
  std::vector<std::string> values = ReadStrings(attr.get(), name, bad);
  if (values.size() != 1) {
    throw IoError(bad +
                  fmt::format("attribute '{}' is not a single string", name));
  }
  return values[0];
}

std::vector<std::string> ReadStringArrayAttribute(hid_t object,
                                                  const char* name,
                                                  const std::string& bad) {
  std::lock_guard lock(Hdf5Mutex());
  const Hid attr = OpenAttribute(object, name, bad);
  return ReadStrings(attr.get(), name, bad);
}

void ReadNumberAttribute(hid_t object,
                         const char* name,
                         hid_t mem_type,
                         void* value,
                         const std::string& bad) {
  std::lock_guard lock(Hdf5Mutex());
  const Hid attr = OpenAttribute(object, name, bad);
  const std::string cannot_read =
      bad + fmt::format("cannot read attribute '{}'", name);
  const Hid type = Check(H5Aget_type(attr.get()), H5Tclose, cannot_read);
  const H5T_class_t type_class = H5Tget_class(type.get());
  const Hid space = Check(H5Aget_space(attr.get()), H5Sclose, cannot_read);
  if ((type_class != H5T_INTEGER && type_class != H5T_FLOAT) ||
      H5Sget_simple_extent_npoints(space.get()) != 1) {
    throw IoError(bad + fmt::format("attribute '{}' is not a number", name));
  }
  CheckStatus(H5Aread(attr.get(), mem_type, value), cannot_read);
}

Hid OpenFormattedFile(const std::string& path,
                      const std::string& what,
                      const std::string& format,
                      int version,
                      std::string* bad) {
  *bad = InvalidFilePrefix(path, what);
  std::error_code error;
  if (!std::filesystem::is_regular_file(path, error)) {
    throw IoError(
        fmt::format("{}: no such file (expected a {}, HDF5)", path, what));
  }
  std::lock_guard lock(Hdf5Mutex());
  if (H5Fis_hdf5(path.c_str()) <= 0) {
    throw IoError(*bad + "not an HDF5 file (or truncated)");
  }
  Hid file = Check(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT),
                   H5Fclose,
                   *bad + "cannot open (truncated?)");
  if (H5Aexists(file.get(), "format") <= 0) {
    throw IoError(fmt::format(
        "{}missing attribute 'format' (expected '{}')", *bad, format));
  }
  const std::string found = ReadStringAttribute(file.get(), "format", *bad);
  if (found != format) {
    throw IoError(fmt::format(
        "{}attribute 'format' is '{}', expected '{}'", *bad, found, format));
  }
  if (version > 0) {
    const int found_version =
        ReadNumberAttribute<int32_t>(file.get(), "format_version", *bad);
    if (found_version != version) {
      throw IoError(fmt::format(
          "{}format_version = {}, expected {}", *bad, found_version, version));
    }
  }
  return file;
}

void WriteDataset(hid_t object,
                  const char* name,
                  const std::vector<hsize_t>& dims,
                  hid_t mem_type,
                  hid_t file_type,
                  const void* values,
                  size_t count,
                  const std::string& file) {
  const std::string what = fmt::format("{}: cannot write '{}'", file, name);
  hsize_t total = 1;
  for (hsize_t d : dims) total *= d;
  if (total != count) {
    throw InternalError(
        fmt::format("{}: dataset '{}' has {} values for {} elements",
                    file,
                    name,
                    count,
                    total));
  }
  std::lock_guard lock(Hdf5Mutex());
  const Hid space = Check(
      H5Screate_simple(static_cast<int>(dims.size()), dims.data(), nullptr),
      H5Sclose,
      what);
  const Hid dataset = Check(H5Dcreate2(object,
                                       name,
                                       file_type,
                                       space.get(),
                                       H5P_DEFAULT,
                                       H5P_DEFAULT,
                                       H5P_DEFAULT),
                            H5Dclose,
                            what);
  if (total > 0) {
    CheckStatus(
        H5Dwrite(
            dataset.get(), mem_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, values),
        what);
  }
}

std::vector<hsize_t> DatasetShape(hid_t object,
                                  const char* name,
                                  const std::string& bad) {
  std::lock_guard lock(Hdf5Mutex());
  if (H5Lexists(object, name, H5P_DEFAULT) <= 0) {
    throw IoError(bad + fmt::format("missing dataset '{}'", name));
  }
  const std::string cannot = bad + fmt::format("cannot open '{}'", name);
  const Hid dataset =
      Check(H5Dopen2(object, name, H5P_DEFAULT), H5Dclose, cannot);
  const Hid space = Check(H5Dget_space(dataset.get()), H5Sclose, cannot);
  const int rank = H5Sget_simple_extent_ndims(space.get());
  if (rank < 0) throw IoError(cannot);
  std::vector<hsize_t> dims(rank);
  H5Sget_simple_extent_dims(space.get(), dims.data(), nullptr);
  return dims;
}

namespace {

std::string ShapeText(const std::vector<hsize_t>& dims) {
  if (dims.empty()) return "a scalar";
  std::string text;
  for (size_t i = 0; i < dims.size(); ++i) {
    text += (i == 0 ? "" : " x ") +
            (dims[i] == 0 ? std::string("*") : std::to_string(dims[i]));
  }
  return text;
}

}  // namespace

template <typename T>
std::vector<T> ReadDataset(hid_t object,
                           const char* name,
                           const std::vector<hsize_t>& expected_dims,
                           const std::string& bad,
                           std::vector<hsize_t>* dims) {
  std::lock_guard lock(Hdf5Mutex());
  const std::vector<hsize_t> shape = DatasetShape(object, name, bad);
  bool matches = expected_dims.empty() || expected_dims.size() == shape.size();
  for (size_t i = 0; matches && i < expected_dims.size(); ++i) {
    matches = expected_dims[i] == 0 || expected_dims[i] == shape[i];
  }
  if (!matches) {
    throw IoError(bad + fmt::format("dataset '{}' is {}, expected {}",
                                    name,
                                    ShapeText(shape),
                                    ShapeText(expected_dims)));
  }
  const std::string cannot = bad + fmt::format("cannot read '{}'", name);
  const Hid dataset =
      Check(H5Dopen2(object, name, H5P_DEFAULT), H5Dclose, cannot);
  const Hid type = Check(H5Dget_type(dataset.get()), H5Tclose, cannot);
  const H5T_class_t type_class = H5Tget_class(type.get());
  if (type_class != H5T_INTEGER && type_class != H5T_FLOAT) {
    throw IoError(bad + fmt::format("dataset '{}' is not numeric", name));
  }
  hsize_t total = 1;
  for (hsize_t d : shape) total *= d;
  std::vector<T> values(total);
  if (total > 0) {
    CheckStatus(H5Dread(dataset.get(),
                        NumberType<T>::Memory(),
                        H5S_ALL,
                        H5S_ALL,
                        H5P_DEFAULT,
                        values.data()),
                cannot + " (truncated?)");
  }
  if (dims != nullptr) *dims = shape;
  return values;
}

template std::vector<int32_t> ReadDataset<int32_t>(hid_t,
                                                   const char*,
                                                   const std::vector<hsize_t>&,
                                                   const std::string&,
                                                   std::vector<hsize_t>*);
template std::vector<int64_t> ReadDataset<int64_t>(hid_t,
                                                   const char*,
                                                   const std::vector<hsize_t>&,
                                                   const std::string&,
                                                   std::vector<hsize_t>*);
template std::vector<float> ReadDataset<float>(hid_t,
                                               const char*,
                                               const std::vector<hsize_t>&,
                                               const std::string&,
                                               std::vector<hsize_t>*);
template std::vector<double> ReadDataset<double>(hid_t,
                                                 const char*,
                                                 const std::vector<hsize_t>&,
                                                 const std::string&,
                                                 std::vector<hsize_t>*);

}  // namespace soma::hdf5
