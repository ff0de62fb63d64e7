// Writing a `soma view` page from a task (issue #27): `soma view` itself and
// `soma eval`, whose report links the page of each labelled output.
#pragma once

#include "framework/config/app.h"
#include "framework/config/node.h"
#include "framework/view/view_capture.h"
#include "framework/view/view_data.h"

#include <filesystem>
#include <string>

namespace soma {

/// What goes into a page and how large it may get.
struct ViewPageSettings {
  ViewInputs inputs;
  double max_page_mb = 30.0;  ///< larger pages show every k-th frame
  int sticks = 2;             ///< neighbours per marker on the layout; 0 none
  std::string template_path;  ///< "" = viewer/soma_view.html (resource root)
  /// "" or a `soma solve` output (<take>_stageii.h5) of the capture: its
  /// body posed on every `mesh_every`-th solved frame (0: as often as a
  /// third of max_page_mb allows). Solve frame t is take frame
  /// solve_start + solve_stride * t (the solver.start / solver.stride the
  /// solve ran with).
  std::string solve;
  int mesh_every = 0;
  int solve_start = 0;
  int solve_stride = 1;
};

/// What WriteViewPage wrote.
struct ViewPageResult {
  std::filesystem::path path;
  ViewDataSummary summary;
  int num_labels = 0;
  int num_sticks = 0;
  int64_t bytes = 0;
};

/// Reads the inputs (ReadViewFrames), adds the sticks of the `layout` group's
/// layout on the `body` group's body at rest (cfg; none without labels) and
/// the body meshes of the solve (the `body` group's body, which must be the
/// one the solve fitted), packs the data into the template and writes `out`
/// atomically. IoError when the solve's observed markers are not points of
/// the capture at the frames the mapping gives.
ViewPageResult WriteViewPage(const ConfigNode& cfg,
                             const ViewPageSettings& settings,
                             const std::filesystem::path& out,
                             RunContext& ctx);

}  // namespace soma
