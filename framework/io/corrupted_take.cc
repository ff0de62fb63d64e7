#include "framework/io/corrupted_take.h"

#include "framework/core/error.h"

#include <fmt/format.h>

namespace soma {

CorruptedTake ReadCorruptedTake(const std::filesystem::path& h5) {
  CorruptedTake take;
  take.c3d_path = h5;
  take.c3d_path.replace_extension(".c3d");
  if (!std::filesystem::exists(take.c3d_path)) {
    throw IoError(fmt::format(
        "{}: ground truth needs its corrupted capture {} beside it (as soma "
        "corrupt writes them)",
        h5.string(),
        take.c3d_path.string()));
  }
  take.c3d = ReadC3d(take.c3d_path);
  const DatasetReader reader(h5);
  take.info = reader.info();
  if (reader.num_frames() != take.c3d.num_frames ||
      take.info.num_points != take.c3d.num_points) {
    throw IoError(fmt::format(
        "{}: ground truth has {} frames x {} columns but {} has {} x {}",
        h5.string(),
        reader.num_frames(),
        take.info.num_points,
        take.c3d_path.string(),
        take.c3d.num_frames,
        take.c3d.num_points));
  }
  reader.Read(0, reader.num_frames(), &take.truth);
  return take;
}

}  // namespace soma
