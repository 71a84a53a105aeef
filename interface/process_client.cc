// ProcessEstimator and ProcessController (client.h): a client process spoken to with the
// lockstep protocol of docs/INTERFACE.md.

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <utility>

#include <nlohmann/json.hpp>

#include "interface/child_process.h"
#include "interface/client.h"
#include "interface/framing.h"
#include "interface/protocol.h"

namespace tofu::interface {
namespace {

using Clock = std::chrono::steady_clock;

// Outgoing bytes are written once this many have gathered (or the in-flight limit is
// reached, or tofu waits for an answer): one write per batch instead of one per message.
constexpr std::size_t kFlushBytes = 8192;
// How often a wait for an answer looks whether the client is still alive: its output may
// stay open after it exited, held by a process it started.
constexpr auto kExitCheckPeriod = std::chrono::milliseconds(100);

// What tofu waits for, named in errors: "the estimates answering measurement seq=5".
struct Awaiting {
  const char* what;
  std::int64_t seq = -1;
  std::string ToString() const { return seq < 0 ? what : fmt::format("{} seq={}", what, seq); }
};

// The conversation with one client process: its start and hello, the framed I/O, and the
// failure that ends it (the client killed, a ClientError naming it and its stderr tail).
class Connection {
 public:
  explicit Connection(ProcessClientConfig config) : config_(std::move(config)) {}

  const ProcessClientConfig& config() const { return config_; }
  Encoding encoding() const { return encoding_; }
  bool open() const { return child_ != nullptr; }

  /// Starts the client and exchanges the hellos (the encoding switches after them).
  void Open(std::string_view role) {
    ThrowIfFailed();
    if (child_) throw std::logic_error(fmt::format("{}: started twice", config_.name));
    if (!(config_.timeout_s > 0.0)) {
      Fail(fmt::format("timeout_s must be positive, got {}", config_.timeout_s));
    }
    try {
      child_ = std::make_unique<ChildProcess>(config_.command, config_.working_dir);
    } catch (const std::runtime_error& e) {
      Fail(fmt::format("cannot start: {}", e.what()));
    }
    AppendFrame(HelloMessage(role, config_.name), Encoding::kJson, &out_);
    const Message hello = Receive({"the client's hello"});
    const ClientHello decoded = Decode([&] { return DecodeClientHello(hello); });
    encoding_ = decoded.encoding;
    reader_.SetEncoding(encoding_);
  }

  /// Frames are appended here; they are written by Poll() and while waiting in Receive().
  std::string& outgoing() { return out_; }
  std::size_t unwritten() const { return out_.size() - out_written_; }

  /// One round of I/O that never waits: writes what the pipe takes, reads what arrived.
  void Poll() {
    if (!stdout_closed_) Exchange(Clock::time_point::min());
  }
  /// A message already read, or nullopt (no I/O).
  std::optional<Message> Buffered(const Awaiting& awaiting) {
    std::optional<Message> message;
    try {
      message = reader_.Next();
    } catch (const ProtocolError& e) {
      Fail(fmt::format("{} (tofu waited for {})", e.what(), awaiting.ToString()));
    }
    if (message && message->type() == "error") {
      Fail(fmt::format("reported an error: {}", DecodeErrorMessage(*message)));
    }
    return message;
  }
  /// The next message, waiting up to timeout_s for it (writing what is pending meanwhile).
  Message Receive(const Awaiting& awaiting) {
    const auto deadline = Clock::now() + Timeout();
    for (;;) {
      if (std::optional<Message> message = Buffered(awaiting)) return std::move(*message);
      if (stdout_closed_ || exited_) FailExited(awaiting);
      const auto now = Clock::now();
      if (now >= deadline) {
        Fail(fmt::format("no answer within timeout_s = {} s (tofu waited for {})",
                         config_.timeout_s, awaiting.ToString()));
      }
      if (Exchange(std::min(deadline, now + kExitCheckPeriod)) == 0 && !stdout_closed_ &&
          child_->WaitForExit(Clock::time_point::min())) {
        // It exited, but a process it started holds its output open: what it wrote before
        // is read, and then it has exited early.
        Exchange(Clock::time_point::min());
        exited_ = true;
      }
    }
  }

  /// Runs a decoder; its ProtocolError ends the client.
  template <typename Decoder>
  auto Decode(Decoder&& decoder) -> decltype(decoder()) {
    try {
      return decoder();
    } catch (const ProtocolError& e) {
      Fail(e.what());
    }
  }

  /// After `finished`: closes the client's standard input and waits for it to exit with
  /// status 0 (timeout_s), then ends its group.
  void Close() {
    child_->CloseStdin();
    const auto deadline = Clock::now() + Timeout();
    // Whatever it still writes is read (and dropped), so that it cannot block on a full
    // pipe, until its output closes or it exits (a process it started may hold the pipe).
    std::string ignored;
    while (!stdout_closed_) {
      const auto now = Clock::now();
      if (now >= deadline) break;
      stdout_closed_ =
          child_->Communicate({}, &ignored, std::min(deadline, now + kExitCheckPeriod)).stdout_closed;
      ignored.clear();
      if (child_->WaitForExit(Clock::time_point::min())) break;
    }
    const std::optional<int> status = child_->WaitForExit(deadline);
    if (!status) {
      Fail(fmt::format("did not exit within timeout_s = {} s after finished (its standard input "
                       "was closed)",
                       config_.timeout_s));
    }
    if (*status != 0) {
      Fail(fmt::format("{} after finished (expected status 0)", ChildProcess::DescribeExit(*status)));
    }
    child_->Kill();  // reaps it; anything it left in its group goes too
  }

  /// Ends the client and throws the ClientError "<name>: <what>" with its stderr tail.
  [[noreturn]] void Fail(const std::string& what) {
    std::vector<std::string> tail;
    if (child_) {
      child_->Kill();
      tail = child_->stderr_tail();
    }
    std::string message = fmt::format("{}: {}", config_.name, what);
    if (!tail.empty()) message += fmt::format("; its last standard-error line: {}", tail.back());
    failure_.emplace(message, tail);
    throw *failure_;
  }
  void ThrowIfFailed() const {
    if (failure_) throw *failure_;
  }

  std::vector<std::string> stderr_tail() const {
    return child_ ? child_->stderr_tail() : std::vector<std::string>{};
  }

  /// Ends the client now (its standard error read to the end) and returns its tail.
  std::vector<std::string> End() {
    if (!child_) return {};
    child_->Kill();
    return child_->stderr_tail();
  }

 private:
  Clock::duration Timeout() const {
    return std::chrono::duration_cast<Clock::duration>(
        std::chrono::duration<double>(std::min(config_.timeout_s, 1e6)));
  }

  // Returns the bytes read.
  std::size_t Exchange(Clock::time_point deadline) {
    const ChildProcess::Exchange result = child_->Communicate(
        std::string_view(out_).substr(out_written_), &received_, deadline);
    out_written_ += result.written;
    if (out_written_ == out_.size()) {
      out_.clear();
      out_written_ = 0;
    } else if (out_written_ > (std::size_t{1} << 20)) {
      out_.erase(0, out_written_);
      out_written_ = 0;
    }
    if (!received_.empty()) {
      reader_.Feed(received_);
      received_.clear();
    }
    if (result.stdout_closed) stdout_closed_ = true;
    return result.read;
  }

  [[noreturn]] void FailExited(const Awaiting& awaiting) {
    // A client that closes its output is about to exit: give it a moment to say how.
    const std::optional<int> status =
        child_->WaitForExit(Clock::now() + std::chrono::milliseconds(500));
    const std::string how = status ? ChildProcess::DescribeExit(*status)
                                   : std::string("closed its standard output");
    const std::string cut =
        reader_.buffered() > 0
            ? fmt::format(" (its last message was cut off after {} bytes)", reader_.buffered())
            : "";
    Fail(fmt::format("{} while tofu waited for {}{}; a client answers every message until "
                     "finished",
                     how, awaiting.ToString(), cut));
  }

  ProcessClientConfig config_;
  std::unique_ptr<ChildProcess> child_;
  Encoding encoding_ = Encoding::kJson;
  FrameReader reader_{Encoding::kJson};
  std::string out_;
  std::size_t out_written_ = 0;
  std::string received_;
  bool stdout_closed_ = false;
  bool exited_ = false;  ///< the client exited while its output stays open
  std::optional<ClientError> failure_;
};

}  // namespace

std::string ClientFailureWithStderr(const std::string& what, const std::string& name,
                                    const std::vector<std::string>& stderr_tail) {
  std::string text = what;
  if (!stderr_tail.empty()) {
    text += fmt::format("\n  last lines of {}'s standard error:", name);
    for (const std::string& line : stderr_tail) text += "\n    " + line;
  }
  return text;
}

// ---------------------------------------------------------------------------------------
// ProcessEstimator

struct ProcessEstimator::Impl {
  explicit Impl(ProcessClientConfig config) : connection(std::move(config)) {}

  Connection connection;
  api::EstimatorSetup setup;
  std::int64_t sent = 0;      ///< measurements sent: the next one's seq
  std::int64_t answered = 0;  ///< answers received: the seq the next one must carry
  std::optional<std::int64_t> last_t_ns;
  std::string report_json = "{}";
  bool finished = false;

  void RequireStarted(const char* call) const {
    connection.ThrowIfFailed();
    if (!connection.open()) {
      throw std::logic_error(fmt::format("{}: {} before Start", connection.config().name, call));
    }
    if (finished) {
      throw std::logic_error(fmt::format("{}: {} after Finish", connection.config().name, call));
    }
  }

  // Estimates must not go back in time, across answers as within one.
  void CheckTimes(const std::vector<api::Estimate>& out, std::size_t first, const char* type,
                  std::int64_t seq) {
    for (std::size_t i = first; i < out.size(); ++i) {
      const std::int64_t t_ns = out[i].t_ns;
      if (last_t_ns && t_ns < *last_t_ns) {
        connection.Fail(fmt::format(
            "{}{}: estimates[{}].t_ns: {} is earlier than the previous estimate's t_ns {} "
            "(estimates must not go back in time)",
            type, seq < 0 ? std::string() : fmt::format(" seq={}", seq), i - first, t_ns,
            *last_t_ns));
      }
      last_t_ns = t_ns;
    }
  }

  // A failing answer leaves nothing of itself in `out`: the answers before it are the
  // client's partial output, whole messages only.
  void Accept(const Message& message, std::vector<api::Estimate>* out) {
    const std::size_t first = out->size();
    try {
      connection.Decode([&] { DecodeEstimates(message, answered, out); });
      CheckTimes(*out, first, "estimates", answered);
    } catch (...) {
      out->erase(out->begin() + static_cast<std::ptrdiff_t>(first), out->end());
      throw;
    }
    ++answered;
  }

  // Every answer already read, without waiting.
  void AcceptBuffered(std::vector<api::Estimate>* out) {
    while (answered < sent) {
      std::optional<Message> message =
          connection.Buffered({"the estimates answering measurement", answered});
      if (!message) return;
      Accept(*message, out);
    }
  }

  void WaitForAnswer(std::vector<api::Estimate>* out) {
    Accept(connection.Receive({"the estimates answering measurement", answered}), out);
  }
};

ProcessEstimator::ProcessEstimator(ProcessClientConfig config)
    : impl_(std::make_unique<Impl>(std::move(config))) {}

ProcessEstimator::~ProcessEstimator() = default;

void ProcessEstimator::Start(const api::EstimatorSetup& setup) {
  Impl& m = *impl_;
  Connection& c = m.connection;
  c.Open("estimator");
  m.setup = setup;
  c.Decode([&] { AppendFrame(SetupMessage(setup), c.encoding(), &c.outgoing()); });
  const Message ready = c.Receive({"the ready answering setup"});
  c.Decode([&] { DecodeReady(ready); });
}

void ProcessEstimator::Add(const api::Measurement& measurement, std::vector<api::Estimate>* out) {
  Impl& m = *impl_;
  Connection& c = m.connection;
  m.RequireStarted("Add");
  const auto max_in_flight =
      static_cast<std::int64_t>(std::max<std::size_t>(c.config().max_in_flight, 1));
  m.AcceptBuffered(out);
  while (m.sent - m.answered >= max_in_flight) m.WaitForAnswer(out);
  AppendMeasurementFrame(m.sent, m.setup, measurement, c.encoding(), &c.outgoing());
  ++m.sent;
  if (c.unwritten() >= kFlushBytes || m.sent - m.answered >= max_in_flight) {
    c.Poll();
    m.AcceptBuffered(out);
  }
}

void ProcessEstimator::Drain(std::vector<api::Estimate>* out) {
  Impl& m = *impl_;
  m.RequireStarted("Drain");
  while (m.answered < m.sent) m.WaitForAnswer(out);
}

void ProcessEstimator::Finish(std::vector<api::Estimate>* out) {
  Impl& m = *impl_;
  Connection& c = m.connection;
  Drain(out);
  AppendFrame(FinishMessage(), c.encoding(), &c.outgoing());
  const Message message = c.Receive({"finished"});
  Finished finished = c.Decode([&] { return DecodeFinished(message); });
  m.CheckTimes(finished.estimates, 0, "finished", -1);
  out->insert(out->end(), std::make_move_iterator(finished.estimates.begin()),
              std::make_move_iterator(finished.estimates.end()));
  m.report_json = std::move(finished.report_json);
  m.finished = true;
  c.Close();
}

std::string ProcessEstimator::ReportJson() const { return impl_->report_json; }

std::vector<std::string> ProcessEstimator::End() { return impl_->connection.End(); }

std::vector<std::string> ProcessEstimator::stderr_tail() const {
  return impl_->connection.stderr_tail();
}

// ---------------------------------------------------------------------------------------
// ProcessController

struct ProcessController::Impl {
  explicit Impl(ProcessClientConfig config) : connection(std::move(config)) {}
  Connection connection;
  int arm_count = 6;
  std::int64_t seq = 0;
  bool finished = false;
};

ProcessController::ProcessController(ProcessClientConfig config)
    : impl_(std::make_unique<Impl>(std::move(config))) {}

ProcessController::~ProcessController() = default;

void ProcessController::Start(const api::ControllerSetup& setup) {
  Impl& m = *impl_;
  Connection& c = m.connection;
  c.Open("controller");
  m.arm_count = setup.arm_count;
  c.Decode([&] { AppendFrame(SetupMessage(setup), c.encoding(), &c.outgoing()); });
  const Message ready = c.Receive({"the ready answering setup"});
  c.Decode([&] { DecodeReady(ready); });
}

api::ControlCommand ProcessController::Compute(const api::ControlState& state,
                                               const api::ControlReference& reference) {
  Impl& m = *impl_;
  Connection& c = m.connection;
  c.ThrowIfFailed();
  if (!c.open() || m.finished) {
    throw std::logic_error(fmt::format("{}: Compute {}", c.config().name,
                                       m.finished ? "after Finish" : "before Start"));
  }
  AppendControlFrame(m.seq, state, reference, c.encoding(), &c.outgoing());
  const Message message = c.Receive({"the command answering control", m.seq});
  api::ControlCommand command =
      c.Decode([&] { return DecodeCommand(message, m.seq, m.arm_count); });
  ++m.seq;
  return command;
}

void ProcessController::Finish() {
  Impl& m = *impl_;
  Connection& c = m.connection;
  c.ThrowIfFailed();
  if (!c.open() || m.finished) return;
  m.finished = true;
  AppendFrame(FinishMessage(), c.encoding(), &c.outgoing());
  const Message message = c.Receive({"finished"});
  c.Decode([&] { (void)DecodeFinished(message); });
  c.Close();
}

std::vector<std::string> ProcessController::stderr_tail() const {
  return impl_->connection.stderr_tail();
}

}  // namespace tofu::interface
