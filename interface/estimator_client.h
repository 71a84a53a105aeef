#pragma once
// The client side of the process protocol (docs/INTERFACE.md) for C++ estimators and
// controllers: a program that wants to be a tofu client implements api::Estimator (or
// api::Controller) and calls
//
//   int main() { MyEkf ekf; return ServeEstimator(ekf, STDIN_FILENO, STDOUT_FILENO,
//                                                 Encoding::kMsgpack); }
//
// tofu's own methods run this way in tofu-estimator-host, and so do the benchmarks.

#include "interface/framing.h"
#include "tofu/api.h"

namespace tofu::interface {

/// Serves one conversation on in_fd (tofu's messages) and out_fd (the answers): reads the
/// hello, answers with `encoding` (used both ways from then on), setup → Start → ready,
/// each measurement → Add → estimates, finish → Finish → finished with ReportJson(). Returns
/// 0 after `finished`; on any error (a throwing estimator, a malformed message, EOF before
/// finish) sends {"type": "error"} when it still can, writes the error to stderr and
/// returns 1. Blocking I/O; answers are written in batches, whenever no message is waiting.
int ServeEstimator(api::Estimator& estimator, int in_fd, int out_fd, Encoding encoding);

/// The same for a controller: control → Compute → command.
int ServeController(api::Controller& controller, int in_fd, int out_fd, Encoding encoding);

}  // namespace tofu::interface
