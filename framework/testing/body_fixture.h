// Shared test fixtures (soma_testing_body: links soma::body, for the tests of
// body and the modules above it): bodies built once per test process (building
// the procedural body costs ~0.2 s in Release, several seconds in Debug).
#pragma once

#include "framework/body/body_model.h"

namespace soma::testing {

/// The default procedural body (MakeProceduralBody with default options).
const BodyModel& ProceduralBody();

}  // namespace soma::testing
