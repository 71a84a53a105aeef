// sim::WorldOptions' field table (declared in sim/world.h).

#include "sim/world.h"

namespace tofu::sim {

std::span<const core::OptionField<WorldOptions>> WorldOptions::Fields() {
  using F = core::OptionField<WorldOptions>;
  using R = core::NumberRule;
  using O = WorldOptions;
  static const F kFields[] = {
      F::Name("world", &O::world)  // models/worlds/<world>.xml
          .Doc("world model, models/worlds/<world>.xml"),
      F::Name("robot", &O::robot)  // models/robots/<robot>.xml
          .Doc("robot model, models/robots/<robot>.xml"),
      // A scenario's physics.rate_hz: MuJoCo's timestep is its inverse.
      F::Number("rate_hz", &O::physics_rate_hz, R::Between(100.0, 10000.0, "Hz"))
          .Doc("physics rate; MuJoCo's timestep is its inverse"),
      F::Number("distance_horizon_m", &O::distance_horizon_m, R::Positive("m"))
          .Doc("robot-to-structure distances are tracked up to this range"),
  };
  return kFields;
}

bool WorldOptions::IsValid(std::string* why) const {
  return core::CheckOptionFields<WorldOptions>(*this, Fields(), why);
}

}  // namespace tofu::sim
