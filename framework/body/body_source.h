// Config-selectable sources of bodies (`body=procedural|makehuman|smplx`) and
// marker layouts (`layout=cmu41|pig39|soma53|superset89|file`): the registry
// entries that build a BodyModel / MarkerLayout from a config node.
#pragma once

#include "framework/body/body_model.h"
#include "framework/body/marker_layout.h"

#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// Builds a body (configs/body/).
class BodySource {
 public:
  static constexpr std::string_view kRegistryName = "body";
  virtual ~BodySource() = default;
  virtual BodyModel Build() const = 0;
};

/// Builds a marker layout on a body (configs/layout/). Every layout takes
/// `exclude`: labels to leave out (a subset layout).
class LayoutSource {
 public:
  static constexpr std::string_view kRegistryName = "layout";
  virtual ~LayoutSource() = default;
  virtual MarkerLayout Build(const BodyModel& body) const = 0;
  /// The canonical labels in label-id order, without building a body: what
  /// `soma corrupt` restricts a real take to.
  virtual std::vector<std::string> Labels() const = 0;
};

/// Registers the body and layout sources and their config groups.
void RegisterBodySources();

}  // namespace soma
