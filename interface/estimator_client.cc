#include "interface/estimator_client.h"

#include <poll.h>
#include <unistd.h>

#include <fmt/format.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "interface/child_process.h"
#include "interface/protocol.h"

namespace tofu::interface {
namespace {

// Blocking, buffered I/O on tofu's two pipes. Answers gather in out() and are written
// whenever the client would wait for tofu's next message, so a batch of measurements gets
// one write of its answers.
class Channel {
 public:
  Channel(int in_fd, int out_fd) : in_fd_(in_fd), out_fd_(out_fd) {}

  Encoding encoding() const { return encoding_; }
  void SetEncoding(Encoding encoding) {
    encoding_ = encoding;
    reader_.SetEncoding(encoding);
  }
  std::string& out() { return out_; }

  Message Receive() {
    for (;;) {
      if (std::optional<Message> message = reader_.Next()) return std::move(*message);
      Flush();
      char buffer[65536];
      const ssize_t n = ::read(in_fd_, buffer, sizeof(buffer));
      if (n < 0 && errno == EINTR) continue;
      if (n < 0 && errno == EAGAIN) {
        Wait(in_fd_, POLLIN);
        continue;
      }
      if (n < 0) throw std::runtime_error(fmt::format("reading from tofu: {}", std::strerror(errno)));
      if (n == 0) throw std::runtime_error("tofu closed the connection before finish");
      reader_.Feed(std::string_view(buffer, static_cast<std::size_t>(n)));
    }
  }

  void Flush() {
    std::size_t written = 0;
    while (written < out_.size()) {
      const long n = WriteWithoutSigpipe(out_fd_, out_.data() + written, out_.size() - written);
      if (n > 0) {
        written += static_cast<std::size_t>(n);
      } else if (n < 0 && errno == EAGAIN) {
        Wait(out_fd_, POLLOUT);
      } else if (n < 0 && errno != EINTR) {
        out_.clear();
        throw std::runtime_error(fmt::format("writing to tofu: {}", std::strerror(errno)));
      }
    }
    out_.clear();
  }

 private:
  static void Wait(int fd, short events) {
    pollfd p{fd, events, 0};
    ::poll(&p, 1, -1);
  }

  int in_fd_;
  int out_fd_;
  Encoding encoding_ = Encoding::kJson;
  FrameReader reader_{Encoding::kJson};
  std::string out_;
};

// Reads tofu's hello for `role` and answers with the client's, switching to `encoding`.
void Greet(Channel& channel, const char* role, Encoding encoding) {
  const TofuHello hello = DecodeTofuHello(channel.Receive());
  if (hello.role != role) {
    throw ProtocolError(fmt::format(
        "hello: role: expected \"{}\" (this program serves an {}), got \"{}\"", role, role,
        hello.role));
  }
  // Answered even when the versions differ: tofu refuses it naming both.
  AppendFrame(ClientHelloMessage(encoding), Encoding::kJson, &channel.out());
  channel.SetEncoding(encoding);
  if (hello.version != api::kApiVersion) {
    throw ProtocolError(fmt::format("hello: tofu speaks protocol version {}, this client {}",
                                    hello.version, api::kApiVersion));
  }
}

// Runs a conversation; any error is reported to tofu as an `error` message and on stderr.
template <typename Conversation>
int Serve(int in_fd, int out_fd, Conversation&& conversation) {
  Channel channel(in_fd, out_fd);
  try {
    conversation(channel);
    channel.Flush();
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tofu client: %s\n", e.what());
    try {
      // Answers already made go first: tofu reads them in order, then the error.
      AppendFrame(ErrorMessage(e.what()), channel.encoding(), &channel.out());
      channel.Flush();
    } catch (const std::exception&) {
      // tofu is gone: nobody to tell.
    }
    return 1;
  }
}

[[noreturn]] void Unexpected(const Message& message, const char* expected) {
  throw ProtocolError(fmt::format("expected {}, got a \"{}\" message", expected, message.type()));
}

}  // namespace

int ServeEstimator(api::Estimator& estimator, int in_fd, int out_fd, Encoding encoding) {
  return Serve(in_fd, out_fd, [&](Channel& channel) {
    Greet(channel, "estimator", encoding);
    const api::EstimatorSetup setup = DecodeSetup(channel.Receive());
    estimator.Start(setup);
    AppendFrame(ReadyMessage(), encoding, &channel.out());
    std::vector<api::Estimate> estimates;
    for (;;) {
      const Message message = channel.Receive();
      estimates.clear();
      if (message.type() == "measurement") {
        std::int64_t seq = 0;
        const api::Measurement measurement = DecodeMeasurement(message, setup, &seq);
        estimator.Add(measurement, &estimates);
        AppendEstimatesFrame(seq, estimates.data(), estimates.size(), encoding, &channel.out());
      } else if (message.type() == "finish") {
        estimator.Finish(&estimates);
        AppendFrame(FinishedMessage(estimates, estimator.ReportJson()), encoding, &channel.out());
        return;
      } else {
        Unexpected(message, "a \"measurement\" or \"finish\" message");
      }
    }
  });
}

int ServeController(api::Controller& controller, int in_fd, int out_fd, Encoding encoding) {
  return Serve(in_fd, out_fd, [&](Channel& channel) {
    Greet(channel, "controller", encoding);
    controller.Start(DecodeControllerSetup(channel.Receive()));
    AppendFrame(ReadyMessage(), encoding, &channel.out());
    for (;;) {
      const Message message = channel.Receive();
      if (message.type() == "control") {
        const ControlRequest request = DecodeControl(message);
        AppendCommandFrame(request.seq, controller.Compute(request.state, request.reference),
                           encoding, &channel.out());
      } else if (message.type() == "finish") {
        AppendFrame(nlohmann::json{{"type", "finished"}}, encoding, &channel.out());
        return;
      } else {
        Unexpected(message, "a \"control\" or \"finish\" message");
      }
    }
  });
}

}  // namespace tofu::interface
