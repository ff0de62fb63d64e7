// File utilities: atomic writes (temp file + fsync + rename), reading whole
// files, directories.
#pragma once

#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>

namespace soma {

/// Reads a whole file; throws IoError naming the path if it cannot.
std::string ReadFile(const std::filesystem::path& path);

/// Writes `contents` so that a reader sees either the old file or the new
/// one, never a partial file: write `<path>.tmp.<pid>`, fsync, rename.
void WriteFileAtomic(const std::filesystem::path& path,
                     std::string_view contents);

/// Streaming variant of WriteFileAtomic for large outputs. Write through
/// `stream()`, then `Commit()`; if destroyed without Commit() (an exception
/// unwound), the temp file is removed and the destination is untouched.
class AtomicFileWriter {
 public:
  explicit AtomicFileWriter(std::filesystem::path path,
                            std::ios::openmode mode = std::ios::out);
  AtomicFileWriter(const AtomicFileWriter&) = delete;
  AtomicFileWriter& operator=(const AtomicFileWriter&) = delete;
  ~AtomicFileWriter();

  std::ofstream& stream() { return stream_; }
  /// The temporary path being written (for libraries that open by name).
  const std::filesystem::path& temp_path() const { return temp_path_; }
  /// Flushes, fsyncs and renames the temp file over the destination.
  void Commit();

 private:
  std::filesystem::path path_;
  std::filesystem::path temp_path_;
  std::ofstream stream_;
  bool committed_ = false;
};

/// Renames `temp` over `path` after fsync-ing it (for files written by other
/// libraries, e.g. HDF5, to a temporary name).
void CommitTempFile(const std::filesystem::path& temp,
                    const std::filesystem::path& path);

/// A temp path next to `path`, unique to this process.
std::filesystem::path TempPathFor(const std::filesystem::path& path);

/// Creates `dir` and parents; throws IoError on failure.
void CreateDirectories(const std::filesystem::path& dir);

}  // namespace soma
