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
/// layout on the `body` group's body at rest (cfg; none without labels), packs
/// the data into the template and writes `out` atomically.
ViewPageResult WriteViewPage(const ConfigNode& cfg,
                             const ViewPageSettings& settings,
                             const std::filesystem::path& out,
                             RunContext& ctx);

}  // namespace soma
