// Marker label helpers shared by every reader (C3D, TRC) and layout code.
#pragma once

#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// `meinard:LFHD` -> `LFHD`: the text after the last ':', trimmed of blanks
/// and NULs (C3D labels are blank padded); labels without a prefix are only
/// trimmed.
std::string_view StripSubjectPrefix(std::string_view label);

/// Which of `labels` are Plug-in Gait's virtual points: the points Vicon's
/// Plug-in Gait model computes and Nexus stores beside the markers as
/// ordinary points, with nothing in the file to tell them apart. They are
///  - the segment axes `<segment><O|A|L|P>` (origin, anterior, lateral,
///    proximal) of PEL, HED, TRX and of L/R + CL, FE, FO, HN, HU, RA, TI, TO
///    (`PELO`, `LFEA`, `RHNP`, ...): flagged when the segment's origin and at
///    least two of its other three axes are among the labels, as the model
///    writes them, so that a marker of another set that happens to share a
///    name (`LTOP` alone) is kept;
///  - `CentreOfMass` and `CentreOfMassFloor`.
/// Labels are compared after StripSubjectPrefix, case-sensitively (the
/// model's names are upper case; `LTOE`, `LTIB`, `LFHD` are markers).
std::vector<bool> PlugInGaitVirtualPoints(std::span<const std::string> labels);

}  // namespace soma
