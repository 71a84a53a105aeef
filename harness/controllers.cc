#include "harness/controllers.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "core/error.h"
#include "interface/client.h"
#include "replay/api_convert.h"

namespace tofu::harness {
namespace {

using replay::FromApi;
using replay::ToApi;

constexpr std::size_t kArms = sim::kArmCount;

template <std::size_t N>
bool AllFinite(const std::array<double, N>& values) {
  return std::all_of(values.begin(), values.end(), [](double v) { return std::isfinite(v); });
}

}  // namespace

BuiltinController::BuiltinController(const sim::ControllerOptions& options,
                                     const sim::RigidBodyParams& params)
    : controller_(options, params) {}

void BuiltinController::Start(const api::ControllerSetup&) {}

api::ControlCommand BuiltinController::Compute(const api::ControlState& state,
                                               const api::ControlReference& reference) {
  const sim::RobotState s{state.t_ns, FromApi(state.T_WB.p_m), FromApi(state.T_WB.q_wxyz),
                          FromApi(state.v_W_mps), FromApi(state.omega_B_radps)};
  sim::Reference r;
  r.p_WB = FromApi(reference.T_WB.p_m);
  r.q_WB = FromApi(reference.T_WB.q_wxyz);
  r.v_WB_W = FromApi(reference.v_W_mps);
  r.a_WB_W = FromApi(reference.a_W_mps2);
  r.omega_WB_B = FromApi(reference.omega_B_radps);
  r.alpha_WB_B = FromApi(reference.alpha_B_radps2);
  const sim::Wrench wrench = controller_.Compute(s, r);
  api::ControlCommand command;
  command.force_B_N = ToApi(wrench.force_B_N);
  command.torque_B_Nm = ToApi(wrench.torque_B_Nm);
  return command;
}

api::ControlState ToApiControlState(const sim::RobotState& state, bool from_estimate) {
  api::ControlState s;
  s.t_ns = state.t_ns;
  s.T_WB = {ToApi(state.p_WB), ToApi(state.q_WB)};
  s.v_W_mps = ToApi(state.v_WB_W);
  s.omega_B_radps = ToApi(state.omega_WB_B);
  s.from_estimate = from_estimate;
  return s;
}

api::ControlReference ToApiReference(const sim::Reference& reference) {
  api::ControlReference r;
  r.T_WB = {ToApi(reference.p_WB), ToApi(reference.q_WB)};
  r.v_W_mps = ToApi(reference.v_WB_W);
  r.a_W_mps2 = ToApi(reference.a_WB_W);
  r.omega_B_radps = ToApi(reference.omega_WB_B);
  r.alpha_B_radps2 = ToApi(reference.alpha_WB_B);
  return r;
}

std::unique_ptr<api::Controller> StartController(const replay::ClientSpec* client,
                                                 const sim::ControllerOptions& options,
                                                 const sim::RigidBodyParams& body,
                                                 const sim::AllocationParams& allocation) {
  api::ControllerSetup setup;
  setup.rate_hz = options.rate_hz;
  setup.mass_kg = body.mass_kg;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) setup.inertia_B_kgm2[static_cast<std::size_t>(3 * r + c)] = body.inertia_B_kgm2(r, c);
  }
  setup.gravity_mps2 = body.gravity_mps2;
  setup.arm_count = sim::kArmCount;
  setup.max_rotor_thrust_N = allocation.rotor_max_thrust_N;
  if (client == nullptr) {
    setup.name = kBuiltinControllerName;
    auto controller = std::make_unique<BuiltinController>(options, body);
    controller->Start(setup);
    return controller;
  }
  setup.name = client->Name();
  setup.config_json = client->config_json;
  try {
    std::unique_ptr<api::Controller> controller;
    if (client->kind == replay::ClientSpec::Kind::kProcess) {
      interface::ProcessClientConfig config;
      config.name = client->Name();
      config.command = client->command;
      config.working_dir = client->working_dir;
      config.timeout_s = client->timeout_s;
      config.max_in_flight = 1;
      controller = std::make_unique<interface::ProcessController>(std::move(config));
    } else {
      controller = interface::PluginLibrary::Open(client->library)->CreateController(client->key);
    }
    controller->Start(setup);
    return controller;
  } catch (const interface::ClientError& e) {
    throw core::SimulationError(
        interface::ClientFailureWithStderr(e.what(), client->Name(), e.stderr_tail()));
  } catch (const std::exception& e) {
    throw core::SimulationError(fmt::format("controller {}: {}", client->Name(), e.what()));
  }
}

sim::AllocationResult ComputeActuation(api::Controller& controller, const std::string& name,
                                       const sim::RobotState& state, bool from_estimate,
                                       const sim::Reference& reference,
                                       const sim::Allocator& allocator,
                                       const std::array<double, sim::kArmCount>& tilt_now_rad) {
  api::ControlCommand command;
  try {
    command = controller.Compute(ToApiControlState(state, from_estimate), ToApiReference(reference));
  } catch (const interface::ClientError& e) {
    throw core::SimulationError(interface::ClientFailureWithStderr(e.what(), name, e.stderr_tail()));
  } catch (const std::exception& e) {
    throw core::SimulationError(fmt::format("controller {}: {}", name, e.what()));
  }
  if (command.kind == api::ControlCommand::Kind::kWrench) {
    if (!AllFinite(command.force_B_N) || !AllFinite(command.torque_B_Nm)) {
      throw core::SimulationError(fmt::format(
          "controller {} at t_ns {}: force_B_N/torque_B_Nm: expected finite numbers", name, state.t_ns));
    }
    return allocator.Allocate({FromApi(command.force_B_N), FromApi(command.torque_B_Nm)}, tilt_now_rad);
  }
  if (command.tilt_rad.size() != kArms || command.rotor_thrust_N.size() != kArms) {
    throw core::SimulationError(fmt::format(
        "controller {} at t_ns {}: tilt_rad and rotor_thrust_N: expected {} values each, got {} and {}",
        name, state.t_ns, sim::kArmCount, command.tilt_rad.size(), command.rotor_thrust_N.size()));
  }
  sim::AllocationResult result;
  for (std::size_t i = 0; i < kArms; ++i) {
    if (!std::isfinite(command.tilt_rad[i]) || !std::isfinite(command.rotor_thrust_N[i])) {
      throw core::SimulationError(fmt::format(
          "controller {} at t_ns {}: actuator {}: expected finite numbers", name, state.t_ns, i));
    }
    result.command.tilt_rad[i] = command.tilt_rad[i];
    result.command.rotor_thrust_N[i] = command.rotor_thrust_N[i];
  }
  return result;
}

void FinishController(api::Controller& controller) {
  if (auto* process = dynamic_cast<interface::ProcessController*>(&controller)) {
    try {
      process->Finish();
    } catch (const interface::ClientError&) {
      // The flight is over and scored; a client that stumbles on finish is ended by its
      // destructor (no process left behind).
    }
  }
}

}  // namespace tofu::harness
