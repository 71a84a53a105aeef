// interface/: the process protocol (messages, framing), client processes (start, I/O,
// failures, cleanup) and C++ plug-ins. Clients are Python scripts the tests write (bad
// behaviour on purpose), tests/interface_test_client.cc (a C++ client served by
// ServeEstimator/ServeController) and tests/interface_test_plugin.cc.

#include <signal.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "interface/child_process.h"
#include "interface/client.h"
#include "interface/framing.h"
#include "interface/protocol.h"
#include "tests/test_support.h"

namespace tofu {
namespace {

namespace fs = std::filesystem;
using interface::ClientError;
using interface::Encoding;
using interface::Message;
using interface::ProtocolError;
using nlohmann::json;

constexpr Encoding kEncodings[] = {Encoding::kJson, Encoding::kMsgpack};

std::uint64_t Bits(double x) {
  std::uint64_t bits = 0;
  std::memcpy(&bits, &x, sizeof(bits));
  return bits;
}

// Equal bit for bit; any NaN equals any NaN (JSON carries NaN as null, payload lost).
::testing::AssertionResult SameDouble(double a, double b) {
  if ((std::isnan(a) && std::isnan(b)) || Bits(a) == Bits(b)) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << fmt::format("{} (0x{:016x}) != {} (0x{:016x})", a,
                                                      Bits(a), b, Bits(b));
}

template <typename Array>
void ExpectSame(const Array& a, const Array& b, const std::string& what) {
  ASSERT_EQ(a.size(), b.size()) << what;
  for (std::size_t i = 0; i < a.size(); ++i) EXPECT_TRUE(SameDouble(a[i], b[i])) << what << "[" << i << "]";
}

// Doubles that a careless writer or reader changes.
const std::vector<double>& TrickyDoubles() {
  static const std::vector<double> values = {
      0.1 + 0.2, -0.0, 0.0, 1e300, -1e-300, std::numeric_limits<double>::denorm_min(),
      -4.9406564584124654e-324, 2.2250738585072009e-308,  // largest subnormal
      std::numeric_limits<double>::min(), std::numeric_limits<double>::max(),
      std::numeric_limits<double>::lowest(), 1.0 / 3.0, 3.141592653589793, 1.0, -2.0,
      9007199254740993.0, 123456789.12345679, 5e-324 * 3, 1e21, 1e22, 123e-20, 0.30000000000000004};
  return values;
}

api::EstimatorSetup TestSetup() {
  api::EstimatorSetup setup;
  setup.method = "external:test";
  setup.imu = 0;
  api::SensorInfo imu;
  imu.name = "imu";
  imu.kind = api::SensorKind::kImu;
  api::SensorInfo vio;
  vio.name = "vio";
  vio.kind = api::SensorKind::kPose;
  vio.T_Is = {{0.1, -0.02, 0.3}, {0.7071067811865476, 0.0, 0.7071067811865475, 0.0}};
  vio.covariance_stated = false;
  api::SensorInfo leica;
  leica.name = "leica \"total station\"";  // a name that needs escaping in JSON
  leica.kind = api::SensorKind::kPosition;
  leica.T_Is.p_m = {0.0, 0.0, -0.05};
  setup.sensors = {imu, vio, leica};
  setup.gravity_mps2 = 9.80665;
  setup.config_json = R"({"accel_noise_density": 0.02, "nested": {"list": [1, 2.5, "x"]}})";
  setup.calibration_yaml = "sensors:\n  imu: {rate_hz: 200}\n";
  setup.estimation_yaml = "methods: [consensus]\n";
  return setup;
}

// A stream of every kind (IMU mostly, poses with and without twist, positions), increasing
// in time, with the tricky doubles spread over its numbers.
std::vector<api::Measurement> TestStream(std::size_t count) {
  const std::vector<double>& tricky = TrickyDoubles();
  std::size_t k = 0;
  const auto next = [&] { return tricky[k++ % tricky.size()]; };
  std::vector<api::Measurement> stream;
  for (std::size_t i = 0; i < count; ++i) {
    api::Measurement m;
    m.t_ns = 1'000'000'000 + static_cast<std::int64_t>(i) * 5'000'000;
    m.arrival_ns = m.t_ns + 1234;
    switch (i % 6) {
      case 2:
      case 5:
        m.sensor = 1;
        m.kind = api::SensorKind::kPose;
        // fmod keeps the quaternion's norm finite (tofu refuses others) and its sign bits.
        m.pose.T_Ss = {{next(), next(), next()}, {0.9, std::fmod(next(), 1.0), -0.1, 0.2}};
        for (double& c : m.pose.covariance) c = next();
        m.pose.has_twist = i % 6 == 2;
        if (m.pose.has_twist) {
          m.pose.v_s_mps = {next(), next(), next()};
          m.pose.omega_s_radps = {next(), next(), next()};
          for (double& c : m.pose.twist_covariance) c = next();
        }
        break;
      case 4:
        m.sensor = 2;
        m.kind = api::SensorKind::kPosition;
        m.position.p_Ss_m = {next(), next(), next()};
        for (double& c : m.position.covariance_m2) c = next();
        break;
      default:
        m.kind = api::SensorKind::kImu;
        m.imu.acc_I_mps2 = {next(), next(), -9.81};
        m.imu.gyro_I_radps = {next(), 0.001, next()};
    }
    stream.push_back(m);
  }
  return stream;
}

void ExpectSameMeasurement(const api::Measurement& a, const api::Measurement& b) {
  EXPECT_EQ(a.t_ns, b.t_ns);
  EXPECT_EQ(a.arrival_ns, b.arrival_ns);
  EXPECT_EQ(a.sensor, b.sensor);
  ASSERT_EQ(a.kind, b.kind);
  switch (a.kind) {
    case api::SensorKind::kImu:
      ExpectSame(a.imu.acc_I_mps2, b.imu.acc_I_mps2, "acc");
      ExpectSame(a.imu.gyro_I_radps, b.imu.gyro_I_radps, "gyro");
      break;
    case api::SensorKind::kPose:
      ExpectSame(a.pose.T_Ss.p_m, b.pose.T_Ss.p_m, "p_Ss_m");
      ExpectSame(a.pose.T_Ss.q_wxyz, b.pose.T_Ss.q_wxyz, "q_Ss_wxyz");
      ExpectSame(a.pose.covariance, b.pose.covariance, "covariance");
      EXPECT_EQ(a.pose.has_twist, b.pose.has_twist);
      ExpectSame(a.pose.v_s_mps, b.pose.v_s_mps, "v_s_mps");
      ExpectSame(a.pose.omega_s_radps, b.pose.omega_s_radps, "omega_s_radps");
      ExpectSame(a.pose.twist_covariance, b.pose.twist_covariance, "twist covariance");
      break;
    case api::SensorKind::kPosition:
      ExpectSame(a.position.p_Ss_m, b.position.p_Ss_m, "p_Ss_m");
      ExpectSame(a.position.covariance_m2, b.position.covariance_m2, "covariance_m2");
      break;
  }
}

std::vector<api::Estimate> TestEstimates() {
  const std::vector<double>& tricky = TrickyDoubles();
  std::vector<api::Estimate> estimates(3);
  for (std::size_t i = 0; i < estimates.size(); ++i) {
    api::Estimate& e = estimates[i];
    e.t_ns = std::numeric_limits<std::int64_t>::max() - 10 + static_cast<std::int64_t>(i);
    e.valid = i != 1;
    e.initialized = true;
    e.T_LI = {{tricky[i], tricky[i + 1], tricky[i + 2]}, {0.5, -0.5, 0.5, std::fmod(tricky[i + 3], 1.0)}};
    e.v_L_mps = {tricky[i + 4], tricky[i + 5], tricky[i + 6]};
    e.omega_I_radps = {tricky[i + 7], tricky[i + 8], tricky[i + 9]};
    e.bias_acc_mps2 = {tricky[i + 10], 0.0, -0.0};
    e.bias_gyro_radps = {tricky[i + 11], 1e-9, 2e-9};
  }
  estimates[0].position_covariance_m2 = api::Mat3{1e-4, 1e-6, 0.0, 1e-6, 2e-4, 0.0, 0.0, 0.0, 0.1 + 0.2};
  estimates[2].fused = std::vector<std::string>{"vio", "leica \"ts\"", "gnss/rtk"};
  estimates[1].fused = std::vector<std::string>{};
  return estimates;
}

void ExpectSameEstimate(const api::Estimate& a, const api::Estimate& b) {
  EXPECT_EQ(a.t_ns, b.t_ns);
  EXPECT_EQ(a.valid, b.valid);
  EXPECT_EQ(a.initialized, b.initialized);
  ExpectSame(a.T_LI.p_m, b.T_LI.p_m, "p_LI_m");
  ExpectSame(a.T_LI.q_wxyz, b.T_LI.q_wxyz, "q_LI_wxyz");
  ExpectSame(a.v_L_mps, b.v_L_mps, "v_L_mps");
  ExpectSame(a.omega_I_radps, b.omega_I_radps, "omega_I_radps");
  ExpectSame(a.bias_acc_mps2, b.bias_acc_mps2, "bias_acc_mps2");
  ExpectSame(a.bias_gyro_radps, b.bias_gyro_radps, "bias_gyro_radps");
  ASSERT_EQ(a.position_covariance_m2.has_value(), b.position_covariance_m2.has_value());
  if (a.position_covariance_m2) {
    ExpectSame(*a.position_covariance_m2, *b.position_covariance_m2, "position_covariance_m2");
  }
  EXPECT_EQ(a.fused, b.fused);
}

// The frames of `bytes` as a reader in `encoding` returns them.
std::vector<Message> ReadAll(const std::string& bytes, Encoding encoding) {
  interface::FrameReader reader(encoding);
  reader.Feed(bytes);
  std::vector<Message> messages;
  while (std::optional<Message> message = reader.Next()) messages.push_back(std::move(*message));
  EXPECT_EQ(reader.buffered(), 0u);
  return messages;
}

// `message` framed in `encoding` and read back.
Message Transfer(const json& message, Encoding encoding) {
  std::vector<Message> messages = ReadAll(interface::Frame(message, encoding), encoding);
  if (messages.size() != 1) throw std::runtime_error("expected one message");
  return std::move(messages[0]);
}

// The ProtocolError `call` throws (what()), or a failure.
template <typename Call>
std::string ProtocolErrorOf(Call&& call) {
  try {
    call();
  } catch (const ProtocolError& e) {
    return e.what();
  }
  ADD_FAILURE() << "expected a ProtocolError";
  return {};
}

// ---------------------------------------------------------------------------------------
// Messages

TEST(Protocol, TofuMessagesRoundTripThroughTheClientDecodersInBothEncodings) {
  const api::EstimatorSetup setup = TestSetup();
  for (const Encoding encoding : kEncodings) {
    SCOPED_TRACE(interface::EncodingName(encoding));
    const interface::TofuHello hello =
        interface::DecodeTofuHello(Transfer(interface::HelloMessage("estimator", "external:x"), encoding));
    EXPECT_EQ(hello.version, api::kApiVersion);
    EXPECT_EQ(hello.role, "estimator");
    EXPECT_EQ(hello.name, "external:x");
    EXPECT_EQ(hello.encodings, (std::vector<std::string>{"json", "msgpack"}));

    const api::EstimatorSetup decoded = interface::DecodeSetup(Transfer(interface::SetupMessage(setup), encoding));
    EXPECT_EQ(decoded.method, setup.method);
    EXPECT_EQ(decoded.imu, setup.imu);
    ASSERT_EQ(decoded.sensors.size(), setup.sensors.size());
    for (std::size_t i = 0; i < setup.sensors.size(); ++i) {
      EXPECT_EQ(decoded.sensors[i].name, setup.sensors[i].name);
      EXPECT_EQ(decoded.sensors[i].kind, setup.sensors[i].kind);
      ExpectSame(decoded.sensors[i].T_Is.p_m, setup.sensors[i].T_Is.p_m, "T_Is.p_m");
      ExpectSame(decoded.sensors[i].T_Is.q_wxyz, setup.sensors[i].T_Is.q_wxyz, "T_Is.q_wxyz");
      EXPECT_EQ(decoded.sensors[i].covariance_stated, setup.sensors[i].covariance_stated);
    }
    EXPECT_TRUE(SameDouble(decoded.gravity_mps2, setup.gravity_mps2));
    EXPECT_EQ(json::parse(decoded.config_json), json::parse(setup.config_json));
    EXPECT_EQ(decoded.calibration_yaml, setup.calibration_yaml);
    EXPECT_EQ(decoded.estimation_yaml, setup.estimation_yaml);

    const std::vector<api::Measurement> stream = TestStream(36);
    for (std::size_t i = 0; i < stream.size(); ++i) {
      std::int64_t seq = -1;
      const api::Measurement m = interface::DecodeMeasurement(
          Transfer(interface::MeasurementMessage(static_cast<std::int64_t>(i), setup, stream[i]), encoding),
          setup, &seq);
      EXPECT_EQ(seq, static_cast<std::int64_t>(i));
      ExpectSameMeasurement(m, stream[i]);
    }

    api::ControllerSetup controller;
    controller.name = "external:pd";
    controller.rate_hz = 250.0;
    controller.mass_kg = 4.2;
    controller.inertia_B_kgm2 = {0.1, 0.0, 0.0, 0.0, 0.1 + 0.2, 0.0, 0.0, 0.0, 0.2};
    controller.arm_count = 6;
    controller.max_rotor_thrust_N = 12.5;
    controller.config_json = R"({"kp": [1, 2, 3]})";
    const api::ControllerSetup decoded_controller =
        interface::DecodeControllerSetup(Transfer(interface::SetupMessage(controller), encoding));
    EXPECT_EQ(decoded_controller.name, controller.name);
    EXPECT_TRUE(SameDouble(decoded_controller.rate_hz, controller.rate_hz));
    EXPECT_TRUE(SameDouble(decoded_controller.mass_kg, controller.mass_kg));
    ExpectSame(decoded_controller.inertia_B_kgm2, controller.inertia_B_kgm2, "inertia");
    EXPECT_EQ(decoded_controller.arm_count, controller.arm_count);
    EXPECT_TRUE(SameDouble(decoded_controller.max_rotor_thrust_N, controller.max_rotor_thrust_N));
    EXPECT_EQ(json::parse(decoded_controller.config_json), json::parse(controller.config_json));

    api::ControlState state;
    state.t_ns = 123456789012;
    state.T_WB = {{1.0, -0.0, 1e300}, {1.0, 0.0, 0.0, 0.0}};
    state.v_W_mps = {0.1 + 0.2, 0.0, 0.0};
    state.omega_B_radps = {std::numeric_limits<double>::denorm_min(), 0.0, 0.0};
    state.from_estimate = true;
    api::ControlReference reference;
    reference.T_WB.p_m = {1.0, 2.0, 3.0};
    reference.a_W_mps2 = {0.0, 0.0, 9.81};
    reference.alpha_B_radps2 = {1.0 / 3.0, 0.0, -1.0};
    const interface::ControlRequest request =
        interface::DecodeControl(Transfer(interface::ControlMessage(41, state, reference), encoding));
    EXPECT_EQ(request.seq, 41);
    EXPECT_EQ(request.state.t_ns, state.t_ns);
    ExpectSame(request.state.T_WB.p_m, state.T_WB.p_m, "state p");
    ExpectSame(request.state.v_W_mps, state.v_W_mps, "state v");
    ExpectSame(request.state.omega_B_radps, state.omega_B_radps, "state omega");
    EXPECT_TRUE(request.state.from_estimate);
    ExpectSame(request.reference.T_WB.p_m, reference.T_WB.p_m, "reference p");
    ExpectSame(request.reference.a_W_mps2, reference.a_W_mps2, "reference a");
    ExpectSame(request.reference.alpha_B_radps2, reference.alpha_B_radps2, "reference alpha");

    interface::DecodeFinish(Transfer(interface::FinishMessage(), encoding));
  }
}

TEST(Protocol, ClientMessagesRoundTripThroughTofusDecodersInBothEncodings) {
  for (const Encoding encoding : kEncodings) {
    SCOPED_TRACE(interface::EncodingName(encoding));
    const interface::ClientHello hello =
        interface::DecodeClientHello(Transfer(interface::ClientHelloMessage(Encoding::kMsgpack), encoding));
    EXPECT_EQ(hello.version, api::kApiVersion);
    EXPECT_EQ(hello.encoding, Encoding::kMsgpack);
    EXPECT_EQ(interface::DecodeClientHello(json{{"type", "hello"}, {"version", 2}}).encoding,
              Encoding::kJson);
    interface::DecodeReady(Transfer(interface::ReadyMessage(), encoding));

    const std::vector<api::Estimate> estimates = TestEstimates();
    const std::vector<api::Estimate> decoded =
        interface::DecodeEstimates(Transfer(interface::EstimatesMessage(7, estimates), encoding), 7);
    ASSERT_EQ(decoded.size(), estimates.size());
    for (std::size_t i = 0; i < decoded.size(); ++i) ExpectSameEstimate(decoded[i], estimates[i]);
    EXPECT_TRUE(interface::DecodeEstimates(Transfer(interface::EstimatesMessage(8, {}), encoding), 8).empty());

    api::ControlCommand wrench;
    wrench.force_B_N = {0.1 + 0.2, -0.0, 41.202};
    wrench.torque_B_Nm = {1e-300, 0.0, -1.0};
    const api::ControlCommand decoded_wrench =
        interface::DecodeCommand(Transfer(interface::CommandMessage(3, wrench), encoding), 3, 6);
    EXPECT_EQ(decoded_wrench.kind, api::ControlCommand::Kind::kWrench);
    ExpectSame(decoded_wrench.force_B_N, wrench.force_B_N, "force");
    ExpectSame(decoded_wrench.torque_B_Nm, wrench.torque_B_Nm, "torque");

    api::ControlCommand actuators;
    actuators.kind = api::ControlCommand::Kind::kActuators;
    actuators.tilt_rad = {0.1, -0.2, 0.3, 1.0 / 3.0, 0.0, -0.0};
    actuators.rotor_thrust_N = {1, 2, 3, 4, 5, 6.5};
    const api::ControlCommand decoded_actuators =
        interface::DecodeCommand(Transfer(interface::CommandMessage(4, actuators), encoding), 4, 6);
    EXPECT_EQ(decoded_actuators.kind, api::ControlCommand::Kind::kActuators);
    ExpectSame(decoded_actuators.tilt_rad, actuators.tilt_rad, "tilt");
    ExpectSame(decoded_actuators.rotor_thrust_N, actuators.rotor_thrust_N, "thrust");

    const interface::Finished finished = interface::DecodeFinished(
        Transfer(interface::FinishedMessage(estimates, R"({"iterations": 12, "note": "ok"})"), encoding));
    ASSERT_EQ(finished.estimates.size(), estimates.size());
    ExpectSameEstimate(finished.estimates[2], estimates[2]);
    EXPECT_EQ(json::parse(finished.report_json), json::parse(R"({"iterations": 12, "note": "ok"})"));
    const interface::Finished bare = interface::DecodeFinished(json{{"type", "finished"}});
    EXPECT_TRUE(bare.estimates.empty());
    EXPECT_EQ(bare.report_json, "{}");

    EXPECT_EQ(interface::DecodeErrorMessage(Transfer(interface::ErrorMessage("diverged: 3 σ"), encoding)),
              "diverged: 3 σ");
  }
}

TEST(Protocol, DirectFramesHoldTheJsonValuesOfTheMessages) {
  const api::EstimatorSetup setup = TestSetup();
  const std::vector<api::Measurement> stream = TestStream(12);
  const std::vector<api::Estimate> estimates = TestEstimates();
  api::ControlState state;
  state.T_WB.p_m = {1.5, 2.5, 3.5};
  api::ControlReference reference;
  api::ControlCommand command;
  command.kind = api::ControlCommand::Kind::kActuators;
  command.tilt_rad = {0.1, 0.2};
  command.rotor_thrust_N = {1.0, 2.0};
  for (const Encoding encoding : kEncodings) {
    SCOPED_TRACE(interface::EncodingName(encoding));
    std::string bytes;
    std::vector<json> expected;
    for (std::size_t i = 0; i < stream.size(); ++i) {
      interface::AppendMeasurementFrame(static_cast<std::int64_t>(i), setup, stream[i], encoding, &bytes);
      expected.push_back(interface::MeasurementMessage(static_cast<std::int64_t>(i), setup, stream[i]));
    }
    interface::AppendEstimatesFrame(5, estimates.data(), estimates.size(), encoding, &bytes);
    expected.push_back(interface::EstimatesMessage(5, estimates));
    interface::AppendControlFrame(6, state, reference, encoding, &bytes);
    expected.push_back(interface::ControlMessage(6, state, reference));
    interface::AppendCommandFrame(7, command, encoding, &bytes);
    expected.push_back(interface::CommandMessage(7, command));
    const std::vector<Message> messages = ReadAll(bytes, encoding);
    ASSERT_EQ(messages.size(), expected.size());
    for (std::size_t i = 0; i < messages.size(); ++i) {
      // Compared as text: nlohmann's dump is canonical (sorted keys, one form per double).
      EXPECT_EQ(messages[i].ToJson().dump(), expected[i].dump()) << "message " << i;
    }
  }
}

TEST(Protocol, DoublesAndInt64RoundTripBitForBit) {
  api::EstimatorSetup setup = TestSetup();
  const std::vector<double>& tricky = TrickyDoubles();
  for (const Encoding encoding : kEncodings) {
    SCOPED_TRACE(interface::EncodingName(encoding));
    for (std::size_t i = 0; i < tricky.size(); ++i) {
      api::Measurement m;
      m.t_ns = i % 2 == 0 ? std::numeric_limits<std::int64_t>::min() : std::numeric_limits<std::int64_t>::max();
      m.arrival_ns = (std::int64_t{1} << 62) + 1;
      m.imu.acc_I_mps2 = {tricky[i], -tricky[i], tricky[(i + 1) % tricky.size()]};
      m.imu.gyro_I_radps = {1.0 / (1.0 + static_cast<double>(i)), tricky[i] * 0.5, tricky[i] / 3.0};
      // Both writers, both directions.
      std::string direct;
      interface::AppendMeasurementFrame(9, setup, m, encoding, &direct);
      for (const Message& message :
           {std::move(ReadAll(direct, encoding).at(0)), Transfer(interface::MeasurementMessage(9, setup, m), encoding)}) {
        ExpectSameMeasurement(interface::DecodeMeasurement(message, setup), m);
      }
      api::Estimate e;
      e.t_ns = m.t_ns;
      e.T_LI.p_m = m.imu.acc_I_mps2;
      e.T_LI.q_wxyz = {tricky[i] == 0.0 ? 1.0 : tricky[i], 0.0, 0.0, 0.0};
      e.v_L_mps = m.imu.gyro_I_radps;
      std::string answer;
      interface::AppendEstimatesFrame(9, &e, 1, encoding, &answer);
      // A quaternion must have a finite norm: the extremes are refused, with a clear error.
      const double norm2 = e.T_LI.q_wxyz[0] * e.T_LI.q_wxyz[0];
      if (!(norm2 > 0.0) || !std::isfinite(norm2)) {
        EXPECT_CONTAINS(ProtocolErrorOf([&] { interface::DecodeEstimates(ReadAll(answer, encoding).at(0), 9); }),
                        "estimates[0].q_LI_wxyz: expected a quaternion");
        continue;
      }
      const std::vector<api::Estimate> back = interface::DecodeEstimates(ReadAll(answer, encoding).at(0), 9);
      ASSERT_EQ(back.size(), 1u);
      ExpectSameEstimate(back[0], e);
    }
  }
}

TEST(Protocol, NonFiniteMeasurementNumbersAreNullInJsonAndThemselvesInMsgpack) {
  const api::EstimatorSetup setup = TestSetup();
  api::Measurement m;
  m.imu.acc_I_mps2 = {std::nan(""), std::numeric_limits<double>::infinity(), 1.0};
  std::string json_frame;
  interface::AppendMeasurementFrame(0, setup, m, Encoding::kJson, &json_frame);
  EXPECT_CONTAINS(json_frame, "\"acc_I_mps2\":[null,null,1.0]");
  const api::Measurement from_json =
      interface::DecodeMeasurement(ReadAll(json_frame, Encoding::kJson).at(0), setup);
  EXPECT_TRUE(std::isnan(from_json.imu.acc_I_mps2[0]));
  EXPECT_TRUE(std::isnan(from_json.imu.acc_I_mps2[1]));  // JSON cannot tell Inf from NaN
  std::string msgpack_frame;
  interface::AppendMeasurementFrame(0, setup, m, Encoding::kMsgpack, &msgpack_frame);
  const api::Measurement from_msgpack =
      interface::DecodeMeasurement(ReadAll(msgpack_frame, Encoding::kMsgpack).at(0), setup);
  EXPECT_TRUE(std::isnan(from_msgpack.imu.acc_I_mps2[0]));
  EXPECT_EQ(from_msgpack.imu.acc_I_mps2[1], std::numeric_limits<double>::infinity());
}

// A valid estimate as a client writes it.
json GoodEstimate() {
  return {{"t_ns", 100}, {"valid", true}, {"p_LI_m", {0, 0, 1.5}}, {"q_LI_wxyz", {1, 0, 0, 0}},
          {"v_L_mps", {0, 0, 0}}, {"omega_I_radps", {0, 0, 0}}};
}

json EstimatesWith(const std::function<void(json&)>& edit) {
  json message = {{"type", "estimates"}, {"seq", 3}, {"estimates", {GoodEstimate(), GoodEstimate()}}};
  edit(message);
  return message;
}

TEST(Protocol, BadEstimatesNameMessageFieldAndExpectedForm) {
  const std::vector<std::pair<json, std::string>> cases = {
      {EstimatesWith([](json& m) { m["estimates"][1].erase("q_LI_wxyz"); }),
       "estimates seq=3: estimates[1].q_LI_wxyz: missing; expected an array of 4 finite numbers"},
      {EstimatesWith([](json& m) { m["estimates"][1]["q_LI_wxyz"] = {1, 0, 0}; }),
       "estimates seq=3: estimates[1].q_LI_wxyz: expected an array of 4 finite numbers, got [1,0,0]"},
      {EstimatesWith([](json& m) { m["estimates"][0]["p_LI_m"] = {0, nullptr, 0}; }),
       "estimates[0].p_LI_m: expected an array of 3 finite numbers, got [0,null,0] (element 1 is null)"},
      {EstimatesWith([](json& m) { m["estimates"][0]["v_L_mps"] = "fast"; }),
       "estimates[0].v_L_mps: expected an array of 3 finite numbers, got \"fast\""},
      {EstimatesWith([](json& m) { m["estimates"][0]["q_LI_wxyz"] = {0, 0, 0, 0}; }),
       "estimates[0].q_LI_wxyz: expected a quaternion [w, x, y, z] of non-zero, finite norm"},
      {EstimatesWith([](json& m) { m["estimates"][0]["valid"] = 1; }),
       "estimates[0].valid: expected a boolean (true or false), got 1"},
      {EstimatesWith([](json& m) { m["estimates"][0]["t_ns"] = 1.5; }),
       "estimates[0].t_ns: expected an integer (int64), got 1.5"},
      {EstimatesWith([](json& m) { m["estimates"][0]["t_ns"] = 18446744073709551615u; }),
       "estimates[0].t_ns: expected an integer (int64), got 18446744073709551615"},
      {EstimatesWith([](json& m) { m["estimates"][0]["fused"] = {"vio", 3}; }),
       "estimates[0].fused[1]: expected a string, got 3"},
      {EstimatesWith([](json& m) { m["estimates"][0]["position_covariance_m2"] = {1, 2}; }),
       "estimates[0].position_covariance_m2: expected an array of 9 finite numbers"},
      {EstimatesWith([](json& m) { m["estimates"][0]["initialized"] = "yes"; }),
       "estimates[0].initialized: expected a boolean"},
      {EstimatesWith([](json& m) { m["estimates"] = GoodEstimate(); }),
       "estimates seq=3: estimates: expected an array of estimates (objects), got {"},
      {EstimatesWith([](json& m) { m["estimates"][0] = 5; }),
       "estimates[0]: expected an object (an estimate), got 5"},
      {EstimatesWith([](json& m) { m["seq"] = 4; }),
       "estimates seq=4: seq: expected 3 (one answer per message, in order), got 4"},
      {EstimatesWith([](json& m) { m.erase("seq"); }), "estimates seq=3: seq: missing; expected an integer"},
      {EstimatesWith([](json& m) { m["type"] = "ready"; }),
       "type: expected \"estimates\", got \"ready\""},
      {json{{"type", "error"}, {"message", "lost track"}},
       "estimates: got an error message instead: lost track"},
  };
  for (const Encoding encoding : kEncodings) {
    for (const auto& test_case : cases) {
      const json& message = test_case.first;
      SCOPED_TRACE(std::string(interface::EncodingName(encoding)) + ": " + message.dump());
      const std::string error =
          ProtocolErrorOf([&] { interface::DecodeEstimates(Transfer(message, encoding), 3); });
      EXPECT_CONTAINS(error, test_case.second);
    }
  }
  // Optional keys may be null (absent) and unknown keys are ignored.
  const std::vector<api::Estimate> ok = interface::DecodeEstimates(
      EstimatesWith([](json& m) {
        m["estimates"][0]["position_covariance_m2"] = nullptr;
        m["estimates"][0]["newer_field"] = {1, 2};
        m["extra"] = "ignored";
      }),
      3);
  ASSERT_EQ(ok.size(), 2u);
  EXPECT_FALSE(ok[0].position_covariance_m2);
  EXPECT_TRUE(ok[0].initialized);  // defaults to valid
  // A long value is cut in the message.
  const std::string long_error = ProtocolErrorOf([&] {
    interface::DecodeEstimates(EstimatesWith([](json& m) { m["estimates"][0]["p_LI_m"] = std::vector<int>(1000, 7); }), 3);
  });
  EXPECT_LT(long_error.size(), 250u) << long_error;
  EXPECT_CONTAINS(long_error, "...");
}

TEST(Protocol, ASetupsSensorKindIsOneOfTheApisNames) {
  json setup = interface::SetupMessage(TestSetup());
  // Every kind reads back as the name it was written with.
  const api::EstimatorSetup decoded = interface::DecodeSetup(Transfer(setup, Encoding::kJson));
  std::set<std::string> kinds;
  for (std::size_t i = 0; i < decoded.sensors.size(); ++i) {
    const std::string written = setup["sensors"][i]["kind"].get<std::string>();
    EXPECT_EQ(written, api::SensorKindName(decoded.sensors[i].kind));
    kinds.insert(written);
  }
  EXPECT_EQ(kinds, (std::set<std::string>{"imu", "pose", "position"}));
  setup["sensors"][0]["kind"] = "sonar";
  EXPECT_CONTAINS(ProtocolErrorOf([&] { interface::DecodeSetup(Transfer(setup, Encoding::kJson)); }),
                  "sensors[0].kind: expected \"imu\", \"pose\" or \"position\", got \"sonar\"");
}

TEST(Protocol, BadCommandsAndHellosAreRefusedWithBothSidesNamed) {
  const json wrench = {{"type", "command"}, {"seq", 0}, {"force_B_N", {0, 0, 40}}, {"torque_B_Nm", {0, 0, 0}}};
  json both = wrench;
  both["tilt_rad"] = std::vector<double>(6, 0.0);
  EXPECT_CONTAINS(ProtocolErrorOf([&] { interface::DecodeCommand(both, 0, 6); }),
                  "command seq=0: holds both a wrench");
  EXPECT_CONTAINS(ProtocolErrorOf([&] { interface::DecodeCommand(json{{"type", "command"}, {"seq", 0}}, 0, 6); }),
                  "expected force_B_N and torque_B_Nm (a wrench) or tilt_rad and rotor_thrust_N");
  json short_actuators = {{"type", "command"}, {"seq", 0}, {"tilt_rad", std::vector<double>(5, 0.0)},
                          {"rotor_thrust_N", std::vector<double>(6, 1.0)}};
  EXPECT_CONTAINS(ProtocolErrorOf([&] { interface::DecodeCommand(short_actuators, 0, 6); }),
                  "command seq=0: tilt_rad: expected an array of 6 finite numbers (one per arm)");
  json missing_torque = wrench;
  missing_torque.erase("torque_B_Nm");
  EXPECT_CONTAINS(ProtocolErrorOf([&] { interface::DecodeCommand(missing_torque, 0, 6); }),
                  "command seq=0: torque_B_Nm: missing");

  EXPECT_CONTAINS(ProtocolErrorOf([] { interface::DecodeClientHello(json{{"type", "hello"}, {"version", 3}}); }),
                  "hello: version: the client speaks protocol version 3, this tofu speaks version 2");
  EXPECT_CONTAINS(ProtocolErrorOf([] {
                    interface::DecodeClientHello(json{{"type", "hello"}, {"version", 2}, {"encoding", "xml"}});
                  }),
                  "hello: encoding: expected \"json\" or \"msgpack\", got \"xml\"");
  EXPECT_CONTAINS(ProtocolErrorOf([] { interface::DecodeClientHello(json{{"type", "hello"}}); }),
                  "hello: version: missing; expected an integer");
  EXPECT_CONTAINS(ProtocolErrorOf([] {
                    interface::DecodeFinished(json{{"type", "finished"}, {"report", {1, 2}}});
                  }),
                  "finished: report: expected an object (stored as client_report), got [1,2]");
}

// ---------------------------------------------------------------------------------------
// Framing

TEST(Framing, ReadsMessagesSplitAnywhereAndSwitchesEncodingBetweenThem) {
  // Blank lines and a CR before the newline are tolerated in JSON lines.
  std::string bytes = "\n \r\n" + interface::Frame(interface::ClientHelloMessage(Encoding::kMsgpack), Encoding::kJson);
  bytes.insert(bytes.size() - 1, "\r");
  const std::size_t json_part = bytes.size();
  for (int seq = 0; seq < 3; ++seq) {
    bytes += interface::Frame(interface::EstimatesMessage(seq, TestEstimates()), Encoding::kMsgpack);
  }
  interface::FrameReader reader(Encoding::kJson);
  std::vector<std::string> types;
  for (std::size_t i = 0; i < bytes.size(); ++i) {
    reader.Feed(std::string_view(bytes).substr(i, 1));
    while (std::optional<Message> message = reader.Next()) {
      types.emplace_back(message->type());
      if (message->type() == "hello") {
        EXPECT_LE(i, json_part);
        reader.SetEncoding(interface::DecodeClientHello(*message).encoding);
      } else {
        EXPECT_EQ(interface::DecodeEstimates(*message, static_cast<std::int64_t>(types.size()) - 2).size(), 3u);
      }
    }
  }
  EXPECT_EQ(types, (std::vector<std::string>{"hello", "estimates", "estimates", "estimates"}));
  EXPECT_EQ(reader.buffered(), 0u);
}

std::string FrameReaderError(const std::string& bytes, Encoding encoding) {
  return ProtocolErrorOf([&] {
    interface::FrameReader reader(encoding);
    reader.Feed(bytes);
    while (reader.Next()) {
    }
  });
}

TEST(Framing, RefusesWhatIsNotOneMessage) {
  EXPECT_CONTAINS(FrameReaderError("{\"type\": \"estimates\", \n", Encoding::kJson), "a line that is not valid JSON");
  EXPECT_CONTAINS(FrameReaderError("{\"type\": \"estimates\", \"x\": NaN}\n", Encoding::kJson),
                  "JSON has no NaN or Infinity, and every number must be finite");
  // Found by fuzz_client_message: nlohmann reports a number beyond double's range as
  // out_of_range, not as a parse error.
  EXPECT_CONTAINS(FrameReaderError("{\"type\": \"estimates\", \"x\": 1e3080}\n", Encoding::kJson),
                  "a line that is not valid JSON (number overflow parsing '1e3080')");
  EXPECT_CONTAINS(FrameReaderError("[1, 2]\n", Encoding::kJson), "a message that is not an object: got [1,2]");
  EXPECT_CONTAINS(FrameReaderError("{\"seq\": 1}\n", Encoding::kJson), "a message without a \"type\" key");
  EXPECT_CONTAINS(FrameReaderError("{\"type\": 5}\n", Encoding::kJson), "\"type\": expected a string, got 5");
  EXPECT_CONTAINS(FrameReaderError(std::string((16u << 20) + 10, ' '), Encoding::kJson), "a line longer than 16 MiB");
  EXPECT_CONTAINS(FrameReaderError(std::string("\x01\x00\x00\x01", 4), Encoding::kMsgpack),
                  "a MessagePack frame of 16777217 bytes: at most 16777216");
  EXPECT_CONTAINS(FrameReaderError(std::string("\0\0\0\0", 4), Encoding::kMsgpack), "a MessagePack frame of 0 bytes");
  EXPECT_CONTAINS(FrameReaderError(std::string("\0\0\0\x02\x93\x01", 6), Encoding::kMsgpack),
                  "a frame that is not valid MessagePack");
  EXPECT_CONTAINS(FrameReaderError(std::string("\0\0\0\x02\x01\x02", 6), Encoding::kMsgpack),
                  "holds more than one MessagePack value");
  EXPECT_CONTAINS(FrameReaderError(std::string("\0\0\0\x01\x05", 5), Encoding::kMsgpack),
                  "a message that is not an object: got 5");
  // An array header claiming more elements than the frame could hold allocates nothing.
  EXPECT_CONTAINS(FrameReaderError(std::string("\0\0\0\x05\xdd\xff\xff\xff\xff", 9), Encoding::kMsgpack),
                  "not valid MessagePack");
  // A map key that is no string: the message is read, its JSON form refused.
  std::vector<Message> odd = ReadAll(std::string("\0\0\0\x0a\x82\xa4type\xa1x\x01\x02", 14), Encoding::kMsgpack);
  ASSERT_EQ(odd.size(), 1u);
  EXPECT_EQ(odd[0].type(), "x");
  EXPECT_CONTAINS(ProtocolErrorOf([&] { (void)odd[0].ToJson(); }), "a map key that is not a string");
}

// ---------------------------------------------------------------------------------------
// Client processes

// A Python client that behaves, or misbehaves as its first argument says; it writes its pid
// (its process group's id) to the file of its second.
constexpr const char* kPythonEstimator = R"PY(
import json, os, subprocess, sys, time
mode, pid_file = sys.argv[1], sys.argv[2]
with open(pid_file, "w") as f:
    f.write(str(os.getpid()))
def send(message):
    sys.stdout.write(json.dumps(message) + "\n")
    sys.stdout.flush()
sys.stderr.write("client: starting in mode %s\n" % mode)
sys.stderr.flush()
hello = json.loads(sys.stdin.readline())
assert hello["type"] == "hello" and hello["role"] == "estimator", hello
if mode == "garbage_hello":
    sys.stdout.write("hello tofu\n")
    sys.stdout.flush()
    time.sleep(100)
send({"type": "hello", "version": 3 if mode == "other_version" else 2})
setup = json.loads(sys.stdin.readline())
if mode == "grandchild":
    subprocess.Popen(["sleep", "1000"])
if mode == "exit_after_ready":
    send({"type": "ready"})
    sys.exit(0)
send({"type": "ready"})
count = 0
for line in sys.stdin:
    m = json.loads(line)
    if m["type"] == "finish":
        send({"type": "finished", "estimates": [], "report": {"count": count, "method": setup["method"]}})
        break
    seq = m["seq"]
    count += 1
    e = {"t_ns": m["t_ns"], "valid": True, "p_LI_m": m.get("acc_I_mps2", m.get("p_Ss_m")),
         "q_LI_wxyz": m.get("q_Ss_wxyz", [1, 0, 0, 0]), "v_L_mps": [0, 0, 0],
         "omega_I_radps": [0, 0, 0], "fused": [m["sensor"]]}
    estimates = [e]
    if seq == 3:
        if mode in ("exit_early", "grandchild"):
            sys.stderr.write("Traceback (most recent call last):\nZeroDivisionError: division by zero\n")
            sys.exit(3)
        if mode == "hang":
            time.sleep(1000)
        if mode == "malformed":
            sys.stdout.write('{"type": "estimates", "seq": 3, \n')
            sys.stdout.flush()
            continue
        if mode == "missing_field":
            del e["q_LI_wxyz"]
        if mode == "nan":
            e["p_LI_m"] = [float("nan"), 0, 0]
        if mode == "backwards":
            e["t_ns"] = 0
        if mode == "wrong_seq":
            seq = 7
        if mode == "error":
            send({"type": "error", "message": "my filter diverged"})
            sys.exit(1)
    if mode == "big":
        estimates = [e] * 40
    send({"type": "estimates", "seq": seq, "estimates": estimates})
if mode == "no_exit":
    time.sleep(1000)
if mode == "exit_nonzero":
    sys.exit(2)
)PY";

constexpr const char* kPythonController = R"PY(
import json, sys
mode = sys.argv[1]
def send(message):
    sys.stdout.write(json.dumps(message) + "\n")
    sys.stdout.flush()
hello = json.loads(sys.stdin.readline())
assert hello["role"] == "controller", hello
send({"type": "hello", "version": 2, "encoding": "json"})
setup = json.loads(sys.stdin.readline())
arms = setup["arm_count"]
send({"type": "ready"})
for line in sys.stdin:
    m = json.loads(line)
    if m["type"] == "finish":
        send({"type": "finished"})
        break
    if mode == "actuators":
        send({"type": "command", "seq": m["seq"], "tilt_rad": [m["state"]["p_WB_m"][0]] * arms,
              "rotor_thrust_N": [setup["mass_kg"]] * (arms - 1 if m["seq"] == 2 else arms)})
    else:
        send({"type": "command", "seq": m["seq"], "force_B_N": m["state"]["p_WB_m"],
              "torque_B_Nm": m["reference"]["alpha_B_radps2"]})
)PY";

// Whether a live (not zombie) process of group `pgid` is left.
bool GroupAlive(pid_t pgid) {
  std::error_code ec;
  for (fs::directory_iterator it("/proc", ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.find_first_not_of("0123456789") != std::string::npos) continue;
    std::ifstream stat(it->path() / "stat");
    std::string line;
    if (!std::getline(stat, line)) continue;
    const std::size_t close = line.rfind(')');
    if (close == std::string::npos) continue;
    char state = 0;
    long ppid = 0;
    long pgrp = 0;
    if (std::sscanf(line.c_str() + close + 1, " %c %ld %ld", &state, &ppid, &pgrp) != 3) continue;
    if (pgrp == pgid && state != 'Z') return true;
  }
  return false;
}

class ProcessClient : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = test::PerTestDirectory("interface_");
    fs::create_directories(dir_);
    test::WriteFile(dir_ / "estimator.py", kPythonEstimator);
    test::WriteFile(dir_ / "controller.py", kPythonController);
  }
  void TearDown() override { interface::SetInterruptCheck({}); }

  interface::ProcessClientConfig Python(const std::string& mode, double timeout_s = 10.0) const {
    interface::ProcessClientConfig config;
    config.name = "external:test";
    config.command = {"/usr/bin/python3", "estimator.py", mode, (dir_ / "pid").string()};
    config.working_dir = dir_;
    config.timeout_s = timeout_s;
    return config;
  }
  interface::ProcessClientConfig Cpp(const std::string& role, Encoding encoding) const {
    interface::ProcessClientConfig config;
    config.name = "external:cpp";
    config.command = {TOFU_TEST_CLIENT, role, interface::EncodingName(encoding)};
    config.working_dir = dir_;
    return config;
  }

  pid_t ClientPid() const {
    std::ifstream in(dir_ / "pid");
    long pid = 0;
    in >> pid;
    return static_cast<pid_t>(pid);
  }

  // The client and whatever it started are gone: reaped, and no live process in its group.
  void ExpectNothingLeft() const {
    const pid_t pid = ClientPid();
    ASSERT_GT(pid, 0) << "the client wrote no pid";
    EXPECT_TRUE(test::WaitUntil([&] { return !GroupAlive(pid); }, std::chrono::seconds(5)))
        << "a process of the client's group " << pid << " is still running";
    EXPECT_TRUE(test::WaitUntil([&] { return ::kill(pid, 0) != 0 && errno == ESRCH; },
                                std::chrono::seconds(5)))
        << "the client " << pid << " was not reaped";
  }

  // Runs the estimator over `count` measurements (then Drain and Finish when asked); the
  // ClientError it throws.
  ClientError RunUntilError(const interface::ProcessClientConfig& config, std::size_t count = 20,
                            bool finish = true) {
    const api::EstimatorSetup setup = TestSetup();
    const std::vector<api::Measurement> stream = TestStream(count);
    try {
      interface::ProcessEstimator estimator(config);
      std::vector<api::Estimate> out;
      estimator.Start(setup);
      for (const api::Measurement& m : stream) estimator.Add(m, &out);
      estimator.Drain(&out);
      if (finish) estimator.Finish(&out);
    } catch (const ClientError& e) {
      return e;
    }
    ADD_FAILURE() << "expected a ClientError";
    return ClientError("");
  }

  fs::path dir_;
};

TEST_F(ProcessClient, PythonEstimatorAnswersEveryMeasurementInOrderBitForBit) {
  for (const std::size_t max_in_flight : {std::size_t{1}, std::size_t{256}}) {
    SCOPED_TRACE(max_in_flight);
    interface::ProcessClientConfig config = Python("good");
    config.max_in_flight = max_in_flight;
    const api::EstimatorSetup setup = TestSetup();
    const std::vector<api::Measurement> stream = TestStream(300);
    interface::ProcessEstimator estimator(config);
    estimator.Start(setup);
    std::vector<api::Estimate> out;
    for (const api::Measurement& m : stream) {
      estimator.Add(m, &out);
      // At most max_in_flight unanswered: the answers so far are all here.
      EXPECT_GE(out.size() + max_in_flight, static_cast<std::size_t>(&m - stream.data()) + 1);
    }
    estimator.Drain(&out);
    ASSERT_EQ(out.size(), stream.size());
    for (std::size_t i = 0; i < stream.size(); ++i) {
      EXPECT_EQ(out[i].t_ns, stream[i].t_ns);
      // Python's json writes the shortest round-trip form: nothing is lost either way.
      const api::Vec3& p = stream[i].kind == api::SensorKind::kImu ? stream[i].imu.acc_I_mps2
                           : stream[i].kind == api::SensorKind::kPose ? stream[i].pose.T_Ss.p_m
                                                                      : stream[i].position.p_Ss_m;
      ExpectSame(out[i].T_LI.p_m, p, "p_LI_m");
      EXPECT_EQ(out[i].fused, std::vector<std::string>{TestSetup().sensors[stream[i].sensor].name});
    }
    estimator.Finish(&out);
    EXPECT_EQ(json::parse(estimator.ReportJson()), (json{{"count", 300}, {"method", "external:test"}}));
    EXPECT_CONTAINS(estimator.stderr_tail().at(0), "client: starting in mode good");
    ExpectNothingLeft();
  }
}

TEST_F(ProcessClient, CppClientRoundTripsEveryNumberInBothEncodings) {
  const api::EstimatorSetup setup = TestSetup();
  const std::vector<api::Measurement> stream = TestStream(600);
  for (const Encoding encoding : kEncodings) {
    SCOPED_TRACE(interface::EncodingName(encoding));
    interface::ProcessEstimator estimator(Cpp("estimator", encoding));
    estimator.Start(setup);
    std::vector<api::Estimate> out;
    for (const api::Measurement& m : stream) estimator.Add(m, &out);
    estimator.Finish(&out);
    ASSERT_EQ(out.size(), stream.size() + 1);
    for (std::size_t i = 0; i < stream.size(); ++i) {
      const api::Measurement& m = stream[i];
      const api::Estimate& e = out[i];
      EXPECT_EQ(e.t_ns, m.t_ns);
      EXPECT_TRUE(SameDouble(e.omega_I_radps[0], static_cast<double>(m.arrival_ns)));
      switch (m.kind) {
        case api::SensorKind::kImu:
          ExpectSame(e.T_LI.p_m, m.imu.acc_I_mps2, "acc");
          ExpectSame(e.v_L_mps, m.imu.gyro_I_radps, "gyro");
          break;
        case api::SensorKind::kPose:
          ExpectSame(e.T_LI.p_m, m.pose.T_Ss.p_m, "p");
          ExpectSame(e.T_LI.q_wxyz, m.pose.T_Ss.q_wxyz, "q");
          ExpectSame(e.bias_acc_mps2, m.pose.v_s_mps, "v_s");
          ExpectSame(e.bias_gyro_radps, m.pose.omega_s_radps, "omega_s");
          EXPECT_EQ(e.fused, std::vector<std::string>{"vio"});
          break;
        case api::SensorKind::kPosition:
          ExpectSame(e.T_LI.p_m, m.position.p_Ss_m, "p");
          ASSERT_TRUE(e.position_covariance_m2);
          ExpectSame(*e.position_covariance_m2, m.position.covariance_m2, "covariance");
          EXPECT_FALSE(e.valid);
          break;
      }
    }
    EXPECT_EQ(json::parse(estimator.ReportJson()),
              (json{{"measurements", 600}, {"method", "external:test"}, {"sensors", 3}}));
  }
}

TEST_F(ProcessClient, ControllersAnswerEveryControlTick) {
  api::ControllerSetup setup;
  setup.name = "external:ctrl";
  setup.rate_hz = 200;
  setup.mass_kg = 4.5;
  setup.arm_count = 6;
  for (const Encoding encoding : kEncodings) {
    SCOPED_TRACE(interface::EncodingName(encoding));
    interface::ProcessController controller(Cpp("controller", encoding));
    setup.config_json = R"({"actuators":true})";
    controller.Start(setup);
    api::ControlState state;
    state.T_WB.q_wxyz = {0.5, 0.1 + 0.2, 0.5, 0.5};
    const api::ControlCommand command = controller.Compute(state, {});
    EXPECT_EQ(command.kind, api::ControlCommand::Kind::kActuators);
    EXPECT_EQ(command.tilt_rad, std::vector<double>(6, 0.1 + 0.2));
    EXPECT_EQ(command.rotor_thrust_N, std::vector<double>(6, 4.5));
    controller.Finish();
  }
  // A Python controller: wrenches, then actuators with a thrust missing at seq 2.
  interface::ProcessClientConfig config = Python("");
  config.command = {"/usr/bin/python3", "controller.py", "wrench"};
  interface::ProcessController wrench(config);
  wrench.Start(setup);
  for (int tick = 0; tick < 5; ++tick) {
    api::ControlState state;
    state.t_ns = tick * 5'000'000;
    state.T_WB.p_m = {0.1 * tick, 0.1 + 0.2, -1.0 / 3.0};
    api::ControlReference reference;
    reference.alpha_B_radps2 = {1e-300, 0.0, 2.5};
    const api::ControlCommand command = wrench.Compute(state, reference);
    EXPECT_EQ(command.kind, api::ControlCommand::Kind::kWrench);
    ExpectSame(command.force_B_N, state.T_WB.p_m, "force");
    ExpectSame(command.torque_B_Nm, reference.alpha_B_radps2, "torque");
  }
  wrench.Finish();
  config.command = {"/usr/bin/python3", "controller.py", "actuators"};
  interface::ProcessController actuators(config);
  actuators.Start(setup);
  actuators.Compute({}, {});
  actuators.Compute({}, {});
  try {
    actuators.Compute({}, {});
    ADD_FAILURE() << "expected a ClientError";
  } catch (const ClientError& e) {
    EXPECT_CONTAINS(e.what(), "external:test: command seq=2: rotor_thrust_N: expected an array of 6 finite "
                              "numbers (one per arm), got [4.5,4.5,4.5,4.5,4.5]");
  }
}

TEST_F(ProcessClient, CannotStartNamesTheCommandAndWhy) {
  interface::ProcessClientConfig config = Python("good");
  config.command = {"no-such-tofu-client-xyz", "--flag"};
  EXPECT_CONTAINS(RunUntilError(config).what(),
                  "external:test: cannot start: `no-such-tofu-client-xyz`: command not found");
  config.command = {"./missing_client.py"};
  EXPECT_CONTAINS(RunUntilError(config).what(),
                  "external:test: cannot start: `./missing_client.py`: cannot execute: No such file or "
                  "directory (working directory " + dir_.string() + ")");
  test::WriteFile(dir_ / "not_executable.py", "print('hi')\n");
  config.command = {"./not_executable.py"};
  EXPECT_CONTAINS(RunUntilError(config).what(), "cannot execute: Permission denied");
  config.command = {"/usr/bin/python3", "estimator.py"};
  config.working_dir = dir_ / "no_such_dir";
  EXPECT_CONTAINS(RunUntilError(config).what(), "cannot enter the working directory " +
                                                    (dir_ / "no_such_dir").string() + ": No such file");
}

TEST_F(ProcessClient, ExitingEarlyIsReportedWithStatusAndStderr) {
  const ClientError error = RunUntilError(Python("exit_early"));
  EXPECT_CONTAINS(error.what(), "external:test: exited with status 3 while tofu waited for the "
                                "estimates answering measurement seq=3");
  EXPECT_CONTAINS(error.what(), "its last standard-error line: ZeroDivisionError: division by zero");
  ASSERT_GE(error.stderr_tail().size(), 2u);
  EXPECT_EQ(error.stderr_tail().back(), "ZeroDivisionError: division by zero");
  EXPECT_EQ(error.stderr_tail().front(), "client: starting in mode exit_early");
  ExpectNothingLeft();
}

TEST_F(ProcessClient, AClientThatStopsReadingDoesNotKillTofuWithSigpipe) {
  // The client exits after ready while tofu writes 4000 measurements into its stdin.
  const ClientError error = RunUntilError(Python("exit_after_ready"), 4000);
  EXPECT_CONTAINS(error.what(), "exited with status 0 while tofu waited for the estimates answering "
                                "measurement seq=0");
  ExpectNothingLeft();
}

TEST_F(ProcessClient, ProcessesTheClientStartedAreEndedToo) {
  const ClientError error = RunUntilError(Python("grandchild"));
  EXPECT_CONTAINS(error.what(), "exited with status 3");
  ExpectNothingLeft();
}

TEST_F(ProcessClient, NoAnswerWithinTheTimeoutEndsTheClient) {
  const auto start = std::chrono::steady_clock::now();
  const ClientError error = RunUntilError(Python("hang", 0.5));
  const double elapsed_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_CONTAINS(error.what(), "external:test: no answer within timeout_s = 0.5 s (tofu waited for the "
                                "estimates answering measurement seq=3)");
  EXPECT_LT(elapsed_s, 5.0);
  EXPECT_CONTAINS(error.stderr_tail().at(0), "client: starting in mode hang");
  ExpectNothingLeft();
}

TEST_F(ProcessClient, MalformedAnswersAreRefusedNamingMessageAndField) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"malformed", "external:test: a line that is not valid JSON"},
      {"nan", "JSON has no NaN or Infinity, and every number must be finite"},
      {"missing_field",
       "external:test: estimates seq=3: estimates[0].q_LI_wxyz: missing; expected an array of 4 finite numbers"},
      {"backwards",
       "external:test: estimates seq=3: estimates[0].t_ns: 0 is earlier than the previous estimate's t_ns "
       "1010000000"},
      {"wrong_seq", "external:test: estimates seq=7: seq: expected 3 (one answer per message, in order), got 7"},
      {"error", "external:test: reported an error: my filter diverged"},
  };
  for (const auto& [mode, expected] : cases) {
    SCOPED_TRACE(mode);
    const ClientError error = RunUntilError(Python(mode));
    EXPECT_CONTAINS(error.what(), expected);
    EXPECT_CONTAINS(error.stderr_tail().at(0), "client: starting in mode " + mode);
    ExpectNothingLeft();
  }
  EXPECT_CONTAINS(RunUntilError(Python("malformed")).what(),
                  "(tofu waited for the estimates answering measurement seq=3)");
}

TEST_F(ProcessClient, BadHellosAndEndingsAreRefused) {
  EXPECT_CONTAINS(RunUntilError(Python("other_version")).what(),
                  "external:test: hello: version: the client speaks protocol version 3, this tofu speaks "
                  "version 2");
  ExpectNothingLeft();
  EXPECT_CONTAINS(RunUntilError(Python("garbage_hello", 2.0)).what(),
                  "a line that is not valid JSON");
  ExpectNothingLeft();
  EXPECT_CONTAINS(RunUntilError(Python("no_exit", 1.0)).what(),
                  "did not exit within timeout_s = 1 s after finished");
  ExpectNothingLeft();
  EXPECT_CONTAINS(RunUntilError(Python("exit_nonzero")).what(),
                  "exited with status 2 after finished (expected status 0)");
  ExpectNothingLeft();
}

TEST_F(ProcessClient, AClientWritingLargeAnswersBeforeReadingNeverDeadlocks) {
  // Each answer is ~10 kB, written before the client reads the next measurement, while
  // tofu streams 256 measurements ahead: both pipes fill up at once.
  interface::ProcessClientConfig config = Python("big", 20.0);
  config.max_in_flight = 256;
  const std::vector<api::Measurement> stream = TestStream(1000);
  interface::ProcessEstimator estimator(config);
  estimator.Start(TestSetup());
  std::vector<api::Estimate> out;
  for (const api::Measurement& m : stream) estimator.Add(m, &out);
  estimator.Finish(&out);
  EXPECT_EQ(out.size(), stream.size() * 40);
  ExpectNothingLeft();
}

TEST_F(ProcessClient, DestroyingARunningClientEndsIt) {
  {
    interface::ProcessEstimator estimator(Python("good"));
    estimator.Start(TestSetup());
    std::vector<api::Estimate> out;
    estimator.Add(TestStream(1)[0], &out);
  }
  ExpectNothingLeft();
}

struct TestInterrupt {};

TEST_F(ProcessClient, AnInterruptCheckAbandonsAWait) {
  int fds[2];
  ASSERT_EQ(::pipe(fds), 0);
  std::atomic<bool> interrupted{false};
  interface::SetInterruptCheck(
      [&] {
        if (interrupted) throw TestInterrupt{};
      },
      fds[0]);
  const auto start = std::chrono::steady_clock::now();
  std::thread signaller([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    interrupted = true;
    [[maybe_unused]] const ssize_t n = ::write(fds[1], "x", 1);
  });
  bool caught = false;
  try {
    interface::ProcessEstimator estimator(Python("hang", 60.0));
    estimator.Start(TestSetup());
    std::vector<api::Estimate> out;
    for (const api::Measurement& m : TestStream(10)) estimator.Add(m, &out);
    estimator.Drain(&out);
  } catch (const TestInterrupt&) {
    caught = true;
  }
  signaller.join();
  EXPECT_TRUE(caught);
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(), 5.0);
  ExpectNothingLeft();
  ::close(fds[0]);
  ::close(fds[1]);
}

TEST(ChildProcess, KeepsTheLastTwentyLinesOfStandardError) {
  interface::ChildProcess child({"/bin/sh", "-c", "for i in $(seq 1 30); do echo line $i >&2; done; "
                                                  "printf 'x%.0s' $(seq 1 3000) >&2; exit 5"},
                                {});
  std::string received;
  while (!child.Communicate({}, &received, std::chrono::steady_clock::now() + std::chrono::seconds(10))
              .stdout_closed) {
  }
  const std::optional<int> status = child.WaitForExit(std::chrono::steady_clock::now() + std::chrono::seconds(10));
  ASSERT_TRUE(status);
  EXPECT_EQ(interface::ChildProcess::DescribeExit(*status), "exited with status 5");
  child.Kill();
  const std::vector<std::string> tail = child.stderr_tail();
  ASSERT_EQ(tail.size(), 20u);
  EXPECT_EQ(tail.front(), "line 12");
  EXPECT_EQ(tail[18], "line 30");
  EXPECT_EQ(tail.back(), std::string(1000, 'x'));  // a long line is cut
  EXPECT_EQ(interface::ChildProcess::DescribeExit(9), "was killed by signal 9 (Killed)");
}

// ---------------------------------------------------------------------------------------
// Plug-ins

TEST(Plugin, LoadsEstimatorsAndControllersThatOutliveTheirLibraryHandle) {
  std::unique_ptr<api::Estimator> estimator;
  std::unique_ptr<api::Controller> controller;
  {
    const std::shared_ptr<interface::PluginLibrary> library = interface::PluginLibrary::Open(TOFU_TEST_PLUGIN);
    estimator = library->CreateEstimator("echo");
    controller = library->CreateController("hover");
  }
  api::EstimatorSetup setup = TestSetup();
  setup.method = "plugin:echo";
  estimator->Start(setup);
  std::vector<api::Estimate> out;
  for (const api::Measurement& m : TestStream(5)) estimator->Add(m, &out);
  estimator->Finish(&out);
  EXPECT_EQ(out.size(), 5u);
  EXPECT_EQ(json::parse(estimator->ReportJson()), (json{{"adds", 5}, {"method", "plugin:echo"}}));
  api::ControllerSetup controller_setup;
  controller_setup.mass_kg = 2.0;
  controller_setup.gravity_mps2 = 9.5;
  controller->Start(controller_setup);
  EXPECT_EQ(controller->Compute({}, {}).force_B_N[2], 19.0);
}

template <typename Call>
std::string ClientErrorOf(Call&& call) {
  try {
    call();
  } catch (const ClientError& e) {
    return e.what();
  }
  ADD_FAILURE() << "expected a ClientError";
  return {};
}

TEST(Plugin, RefusesOtherVersionsAndUnknownNamesAndReportsThrows) {
  EXPECT_CONTAINS(ClientErrorOf([] { interface::PluginLibrary::Open(TOFU_TEST_PLUGIN_WRONG_VERSION); }),
                  "built against tofu API version 3, this tofu speaks version 2");
  EXPECT_CONTAINS(ClientErrorOf([] { interface::PluginLibrary::Open(TOFU_TEST_PLUGIN_NO_VERSION); }),
                  "not a tofu plug-in: it defines no tofu_plugin_api_version");
  EXPECT_CONTAINS(ClientErrorOf([] { interface::PluginLibrary::Open("/no/such/libplugin.so"); }),
                  "plug-in /no/such/libplugin.so: cannot load it: /no/such/libplugin.so: cannot open shared object file");
  const std::shared_ptr<interface::PluginLibrary> library = interface::PluginLibrary::Open(TOFU_TEST_PLUGIN);
  EXPECT_CONTAINS(ClientErrorOf([&] { library->CreateEstimator("nope"); }),
                  "plugin:nope (" + std::string(TOFU_TEST_PLUGIN) + "): the library makes no estimator named \"nope\"");
  EXPECT_CONTAINS(ClientErrorOf([&] { library->CreateController("echo"); }), "makes no controller named \"echo\"");
  std::unique_ptr<api::Estimator> thrower = library->CreateEstimator("thrower");
  thrower->Start(TestSetup());
  std::vector<api::Estimate> out;
  const std::vector<api::Measurement> stream = TestStream(3);
  thrower->Add(stream[0], &out);
  thrower->Add(stream[1], &out);
  EXPECT_CONTAINS(ClientErrorOf([&] { thrower->Add(stream[2], &out); }),
                  "plugin:thrower (" + std::string(TOFU_TEST_PLUGIN) +
                      "): Add (measurement t_ns=1010000000, sensor 1) threw: filter diverged at t_ns 1010000000");
}

}  // namespace
}  // namespace tofu
