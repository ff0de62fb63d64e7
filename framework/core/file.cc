#include "framework/core/file.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <cerrno>
#include <cstring>
#include <fcntl.h>
#include <sstream>
#include <unistd.h>

namespace soma {
namespace {

void FsyncPath(const std::filesystem::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

}  // namespace

std::string ReadFile(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    throw IoError(fmt::format("Cannot open '{}' for reading: {}",
                              path.string(),
                              std::strerror(errno)));
  }
  std::ostringstream buffer;
  buffer << in.rdbuf();
  return buffer.str();
}

std::filesystem::path TempPathFor(const std::filesystem::path& path) {
  return path.string() + fmt::format(".tmp.{}", ::getpid());
}

void CreateDirectories(const std::filesystem::path& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) {
    throw IoError(fmt::format(
        "Cannot create directory '{}': {}", dir.string(), ec.message()));
  }
}

void CommitTempFile(const std::filesystem::path& temp,
                    const std::filesystem::path& path) {
  FsyncPath(temp);
  std::error_code ec;
  std::filesystem::rename(temp, path, ec);
  if (ec) {
    std::filesystem::remove(temp, ec);
    throw IoError(fmt::format(
        "Cannot rename '{}' to '{}'", temp.string(), path.string()));
  }
}

void WriteFileAtomic(const std::filesystem::path& path,
                     std::string_view contents) {
  AtomicFileWriter writer(path, std::ios::out | std::ios::binary);
  writer.stream().write(contents.data(),
                        static_cast<std::streamsize>(contents.size()));
  writer.Commit();
}

AtomicFileWriter::AtomicFileWriter(std::filesystem::path path,
                                   std::ios::openmode mode)
    : path_(std::move(path)), temp_path_(TempPathFor(path_)) {
  if (path_.has_parent_path()) CreateDirectories(path_.parent_path());
  stream_.open(temp_path_, mode);
  if (!stream_) {
    throw IoError(fmt::format("Cannot open '{}' for writing: {}",
                              temp_path_.string(),
                              std::strerror(errno)));
  }
}

AtomicFileWriter::~AtomicFileWriter() {
  if (!committed_) {
    stream_.close();
    std::error_code ec;
    std::filesystem::remove(temp_path_, ec);
  }
}

void AtomicFileWriter::Commit() {
  stream_.flush();
  if (!stream_) {
    throw IoError(fmt::format("Write to '{}' failed", temp_path_.string()));
  }
  stream_.close();
  CommitTempFile(temp_path_, path_);
  committed_ = true;
}

}  // namespace soma
