#pragma once
// The messages of the process protocol (docs/INTERFACE.md): their one schema, both sides.
// tofu's side builds hello, setup, measurement, control and finish, and decodes (strictly)
// the client's hello, ready, estimates, command, finished and error; a C++ client's side
// (estimator_client.h, tests, benchmarks) the reverse.
//
// Every message exists as a JSON value (nlohmann::json: tests, the cold messages). The hot
// ones (measurement, control; estimates, command) are also written straight into a frame
// by Append*Frame: the same bytes Frame(…Message(…)) gives, without building the JSON
// value (tests/interface_test.cc checks both agree). Doubles round-trip bit for bit in
// both encodings; a non-finite number of a tofu message is `null` in JSON (JSON has no
// NaN) and itself in MessagePack.
//
// Decoders throw ProtocolError naming the message (type and seq), the field
// (`estimates[2].q_LI_wxyz`) and the expected form with what came instead.

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "interface/framing.h"
#include "tofu/api.h"

namespace tofu::interface {

// ---------------------------------------------------------------------------------------
// tofu → client

/// {"type": "hello", "protocol": "tofu", "version": 2, "role", "name", "encodings"}.
/// `role` is "estimator" or "controller".
nlohmann::json HelloMessage(std::string_view role, std::string_view name);
/// The estimator's setup; setup.config_json must hold a JSON object (ProtocolError).
nlohmann::json SetupMessage(const api::EstimatorSetup& setup);
nlohmann::json SetupMessage(const api::ControllerSetup& setup);
/// measurement.sensor must index setup.sensors (std::invalid_argument).
nlohmann::json MeasurementMessage(std::int64_t seq, const api::EstimatorSetup& setup,
                                  const api::Measurement& measurement);
void AppendMeasurementFrame(std::int64_t seq, const api::EstimatorSetup& setup,
                            const api::Measurement& measurement, Encoding encoding,
                            std::string* out);
/// t_ns is state.t_ns.
nlohmann::json ControlMessage(std::int64_t seq, const api::ControlState& state,
                              const api::ControlReference& reference);
void AppendControlFrame(std::int64_t seq, const api::ControlState& state,
                        const api::ControlReference& reference, Encoding encoding,
                        std::string* out);
nlohmann::json FinishMessage();

// client → tofu, decoded by tofu. Each checks the message's type first ("expected a
// `ready`, got `estimates`"); an {"type": "error"} message is for DecodeErrorMessage.

struct ClientHello {
  int version = 0;
  Encoding encoding = Encoding::kJson;
};
/// Requires version == api::kApiVersion (else a ProtocolError naming both versions) and an
/// encoding of "json" (the default) or "msgpack".
ClientHello DecodeClientHello(const Message& message);
void DecodeReady(const Message& message);
/// The estimates of an `estimates` answer, appended to *out: every required key, arrays
/// of the stated sizes, finite numbers, booleans, a non-zero quaternion; "fused" an array
/// of strings. `seq` must be expected_seq. Estimates are passed on as sent (a unit
/// quaternion stays bit-identical); tofu normalises the attitude where it uses it.
void DecodeEstimates(const Message& message, std::int64_t expected_seq,
                     std::vector<api::Estimate>* out);
std::vector<api::Estimate> DecodeEstimates(const Message& message, std::int64_t expected_seq);
/// A wrench, or actuator commands with arm_count tilts and thrusts; `seq` must be
/// expected_seq.
api::ControlCommand DecodeCommand(const Message& message, std::int64_t expected_seq,
                                  int arm_count);
struct Finished {
  std::vector<api::Estimate> estimates;
  std::string report_json = "{}";  ///< the "report" object as JSON text
};
Finished DecodeFinished(const Message& message);
/// The text of an {"type": "error", "message": ...} message (a message that is not a
/// string is described instead).
std::string DecodeErrorMessage(const Message& message);

// The same decoders on a JSON value (tests, and callers holding JSON).
ClientHello DecodeClientHello(const nlohmann::json& message);
std::vector<api::Estimate> DecodeEstimates(const nlohmann::json& message,
                                           std::int64_t expected_seq);
api::ControlCommand DecodeCommand(const nlohmann::json& message, std::int64_t expected_seq,
                                  int arm_count);
Finished DecodeFinished(const nlohmann::json& message);

// ---------------------------------------------------------------------------------------
// client → tofu, built by a C++ client

/// {"type": "hello", "version": api::kApiVersion, "encoding"}.
nlohmann::json ClientHelloMessage(Encoding encoding);
nlohmann::json ReadyMessage();
/// Non-finite numbers are written as they are (MessagePack) or as null (JSON): tofu
/// refuses both, naming the field.
nlohmann::json EstimatesMessage(std::int64_t seq, const std::vector<api::Estimate>& estimates);
void AppendEstimatesFrame(std::int64_t seq, const api::Estimate* estimates, std::size_t count,
                          Encoding encoding, std::string* out);
nlohmann::json CommandMessage(std::int64_t seq, const api::ControlCommand& command);
void AppendCommandFrame(std::int64_t seq, const api::ControlCommand& command, Encoding encoding,
                        std::string* out);
/// report_json must hold a JSON object (ProtocolError).
nlohmann::json FinishedMessage(const std::vector<api::Estimate>& estimates,
                               std::string_view report_json = "{}");
nlohmann::json ErrorMessage(std::string_view text);

// tofu → client, decoded by a C++ client.

struct TofuHello {
  int version = 0;
  std::string role;  ///< "estimator" or "controller"
  std::string name;
  std::vector<std::string> encodings;
};
/// Reads any version (the client answers with its own; tofu decides).
TofuHello DecodeTofuHello(const Message& message);
api::EstimatorSetup DecodeSetup(const Message& message);
api::ControllerSetup DecodeControllerSetup(const Message& message);
/// A measurement of `setup` (sensor_index in range, its kind the sensor's). Numbers may be
/// NaN (null in JSON): faulty samples are delivered as they are. *seq (if given) is set.
api::Measurement DecodeMeasurement(const Message& message, const api::EstimatorSetup& setup,
                                   std::int64_t* seq = nullptr);
struct ControlRequest {
  std::int64_t seq = 0;
  api::ControlState state;  ///< state.t_ns is the message's t_ns
  api::ControlReference reference;
};
ControlRequest DecodeControl(const Message& message);
/// Checks the type is "finish".
void DecodeFinish(const Message& message);

}  // namespace tofu::interface
