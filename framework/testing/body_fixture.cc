#include "framework/testing/body_fixture.h"

#include "framework/body/procedural_body.h"

namespace soma::testing {

const BodyModel& ProceduralBody() {
  static const BodyModel body = MakeProceduralBody();
  return body;
}

}  // namespace soma::testing
