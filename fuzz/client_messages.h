#pragma once
// The reader of fuzz_client_message (docs/FUZZING.md), shared with
// tests/fuzz_regression_test.cc: bytes a client process could write, through
// interface::FrameReader as JSON lines, as MessagePack frames, and as JSON lines switching
// to MessagePack after the first message (the hello exchange); every message then through
// every decoder of the protocol, tofu's side and a C++ client's. The promise checked: a
// reader returns or throws interface::ProtocolError, nothing else (no other exception, no
// crash, no sanitizer report, no unbounded allocation).

#include <cstdint>
#include <optional>
#include <string_view>

#include <nlohmann/json.hpp>

#include "interface/framing.h"
#include "interface/protocol.h"

namespace tofu::fuzz {

// Runs one decoder; true when it accepted the message.
template <typename Decode>
bool Accepts(Decode&& decode) {
  try {
    decode();
    return true;
  } catch (const interface::ProtocolError&) {
    return false;
  }
}

/// The number of messages of `bytes` that the decoder of their own type accepted (over the
/// three readings). Throws whatever a decoder throws besides ProtocolError: a finding.
inline int DecodeClientMessages(std::string_view bytes) {
  using interface::Encoding;
  static const api::EstimatorSetup setup = [] {
    api::EstimatorSetup s;
    s.sensors.resize(3);
    s.sensors[0].name = "imu";
    s.sensors[1].name = "vio";
    s.sensors[1].kind = api::SensorKind::kPose;
    s.sensors[2].name = "leica";
    s.sensors[2].kind = api::SensorKind::kPosition;
    return s;
  }();
  int accepted = 0;
  for (int reading = 0; reading < 3; ++reading) {
    interface::FrameReader reader(reading == 1 ? Encoding::kMsgpack : Encoding::kJson);
    // In two parts: a message split across reads is the usual case on a pipe.
    reader.Feed(bytes.substr(0, bytes.size() / 2));
    bool fed = false;
    for (int count = 0; count < 4096; ++count) {
      std::optional<interface::Message> message;
      if (!Accepts([&] { message = reader.Next(); })) break;
      if (!message) {
        if (fed) break;
        reader.Feed(bytes.substr(bytes.size() / 2));
        fed = true;
        --count;
        continue;
      }
      if (reading == 2 && count == 0) reader.SetEncoding(Encoding::kMsgpack);
      const interface::Message& m = *message;
      std::int64_t seq = 0;
      Accepts([&] {
        const nlohmann::json value = m.ToJson();
        if (const auto it = value.find("seq"); it != value.end() && it->is_number_integer()) {
          seq = it->get<std::int64_t>();
        }
      });
      const std::string_view type = m.type();
      const auto own = [&](std::string_view decoder_type, bool ok) {
        if (ok && decoder_type == type) ++accepted;
      };
      own("hello", Accepts([&] { interface::DecodeClientHello(m); }));
      own("ready", Accepts([&] { interface::DecodeReady(m); }));
      own("estimates", Accepts([&] { interface::DecodeEstimates(m, seq); }));
      own("command", Accepts([&] { interface::DecodeCommand(m, seq, 6); }));
      own("finished", Accepts([&] { interface::DecodeFinished(m); }));
      own("error", Accepts([&] { (void)interface::DecodeErrorMessage(m); }));
      // tofu's messages, as a C++ client decodes them.
      Accepts([&] { interface::DecodeTofuHello(m); });
      Accepts([&] { interface::DecodeSetup(m); });
      Accepts([&] { interface::DecodeControllerSetup(m); });
      Accepts([&] { interface::DecodeMeasurement(m, setup); });
      Accepts([&] { interface::DecodeControl(m); });
      Accepts([&] { interface::DecodeFinish(m); });
    }
  }
  return accepted;
}

}  // namespace tofu::fuzz
