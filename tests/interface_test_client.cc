// A C++ process client for tests/interface_test.cc, served by interface::ServeEstimator /
// ServeController: it echoes what it receives into its answers, so the test can check
// that every number crossed the protocol bit for bit, both ways.
//   interface_test_client estimator|controller json|msgpack
#include <unistd.h>

#include <cstdio>
#include <string>
#include <string_view>

#include "interface/estimator_client.h"

namespace {

using namespace tofu;

// One estimate per measurement: its stamp, and its numbers in the estimate's fields.
class EchoEstimator final : public api::Estimator {
 public:
  void Start(const api::EstimatorSetup& setup) override { setup_ = setup; }
  void Add(const api::Measurement& m, std::vector<api::Estimate>* out) override {
    api::Estimate e;
    e.t_ns = m.t_ns;
    e.valid = m.kind != api::SensorKind::kPosition;
    e.initialized = true;
    e.omega_I_radps = {static_cast<double>(m.arrival_ns), static_cast<double>(m.sensor), 0.0};
    switch (m.kind) {
      case api::SensorKind::kImu:
        e.T_LI.p_m = m.imu.acc_I_mps2;
        e.v_L_mps = m.imu.gyro_I_radps;
        break;
      case api::SensorKind::kPose:
        e.T_LI = m.pose.T_Ss;
        e.bias_acc_mps2 = m.pose.v_s_mps;
        e.bias_gyro_radps = m.pose.omega_s_radps;
        e.fused = std::vector<std::string>{setup_.sensors[m.sensor].name};
        break;
      case api::SensorKind::kPosition:
        e.T_LI.p_m = m.position.p_Ss_m;
        e.position_covariance_m2 = m.position.covariance_m2;
        break;
    }
    last_t_ns_ = m.t_ns;
    ++count_;
    out->push_back(e);
  }
  void Finish(std::vector<api::Estimate>* out) override {
    api::Estimate e;
    e.t_ns = last_t_ns_;
    out->push_back(e);
  }
  std::string ReportJson() const override {
    return "{\"measurements\": " + std::to_string(count_) + ", \"method\": \"" + setup_.method +
           "\", \"sensors\": " + std::to_string(setup_.sensors.size()) + "}";
  }

 private:
  api::EstimatorSetup setup_;
  std::int64_t last_t_ns_ = 0;
  int count_ = 0;
};

// A wrench of the state's position and the reference's; actuators when its config asks.
class EchoController final : public api::Controller {
 public:
  void Start(const api::ControllerSetup& setup) override {
    setup_ = setup;
    actuators_ = setup.config_json.find("\"actuators\":true") != std::string::npos;
  }
  api::ControlCommand Compute(const api::ControlState& state,
                              const api::ControlReference& reference) override {
    api::ControlCommand command;
    if (actuators_) {
      command.kind = api::ControlCommand::Kind::kActuators;
      command.tilt_rad.assign(static_cast<std::size_t>(setup_.arm_count), state.T_WB.q_wxyz[1]);
      command.rotor_thrust_N.assign(static_cast<std::size_t>(setup_.arm_count), setup_.mass_kg);
      return command;
    }
    command.force_B_N = state.T_WB.p_m;
    command.torque_B_Nm = reference.alpha_B_radps2;
    return command;
  }

 private:
  api::ControllerSetup setup_;
  bool actuators_ = false;
};

}  // namespace

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: %s estimator|controller json|msgpack\n", argv[0]);
    return 2;
  }
  const interface::Encoding encoding = std::string_view(argv[2]) == "msgpack"
                                           ? interface::Encoding::kMsgpack
                                           : interface::Encoding::kJson;
  if (std::string_view(argv[1]) == "controller") {
    EchoController controller;
    return interface::ServeController(controller, STDIN_FILENO, STDOUT_FILENO, encoding);
  }
  EchoEstimator estimator;
  return interface::ServeEstimator(estimator, STDIN_FILENO, STDOUT_FILENO, encoding);
}
