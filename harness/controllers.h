#pragma once
// Who flies the robot, behind the public api::Controller (include/tofu/api.h): tofu's
// own SE(3) controller (sim::GeometricController) or a user's, a process speaking the
// protocol of docs/INTERFACE.md or a C++ plug-in. The flight loop calls every controller
// alike; a client's failure ends the flight as a simulation failure naming it.

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "harness/closed_loop.h"
#include "replay/estimation_config.h"
#include "sim/allocation.h"
#include "sim/controller.h"
#include "sim/rigid_body.h"
#include "sim/trajectory.h"
#include "tofu/api.h"

namespace tofu::harness {

/// tofu's SE(3) controller as an api::Controller. Its conversions copy every double, so a
/// flight through the interface is bit-identical to one that calls it directly.
class BuiltinController : public api::Controller {
 public:
  BuiltinController(const sim::ControllerOptions& options, const sim::RigidBodyParams& params);
  void Start(const api::ControllerSetup& setup) override;
  api::ControlCommand Compute(const api::ControlState& state,
                              const api::ControlReference& reference) override;

 private:
  sim::GeometricController controller_;
};

/// The controller of a flight: `client` (a scenario's external:/plugins: entry) or, when
/// null, tofu's own; started with the robot's setup. Throws core::SimulationError when a
/// client cannot start.
std::unique_ptr<api::Controller> StartController(const replay::ClientSpec* client,
                                                 const sim::ControllerOptions& options,
                                                 const sim::RigidBodyParams& body,
                                                 const sim::AllocationParams& allocation);

api::ControlState ToApiControlState(const sim::RobotState& state, bool from_estimate);
api::ControlReference ToApiReference(const sim::Reference& reference);

/// One tick of `controller`: its command as actuator commands (a wrench through the
/// allocator). Throws core::SimulationError naming `name` when the controller fails or
/// commands what the robot cannot take (a wrong count, a non-finite value).
sim::AllocationResult ComputeActuation(api::Controller& controller, const std::string& name,
                                       const sim::RobotState& state, bool from_estimate,
                                       const sim::Reference& reference,
                                       const sim::Allocator& allocator,
                                       const std::array<double, sim::kArmCount>& tilt_now_rad);

/// Ends a process controller politely (finish, then wait); others need nothing.
void FinishController(api::Controller& controller);

}  // namespace tofu::harness
