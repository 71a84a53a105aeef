// tofu-estimator-host: tofu's own estimation methods as a process client of the lockstep
// protocol (docs/INTERFACE.md). A scenario names it like any user's estimator,
//   external: {consensus_host: {command: [tofu-estimator-host], config: {method: consensus}}}
// and it gives byte-identical estimate files to the in-process method: the check that the
// protocol loses nothing (tests/client_methods_test.cc), and a template for hosting a C++
// estimator behind the protocol.

#include <unistd.h>

#include <optional>
#include <string>

#include <CLI/CLI.hpp>

#include "harness/hosted_builtin.h"
#include "interface/estimator_client.h"
#include "interface/framing.h"

int main(int argc, char** argv) {
  CLI::App app{"tofu-estimator-host: tofu's own estimation methods behind the lockstep "
               "protocol (docs/INTERFACE.md), on standard input and output"};
  std::optional<std::string> method;
  std::string encoding = "json";
  app.add_option("--method", method,
                 "consensus (default), consensus:<fuse>, naive, single:<s>, fuse:<a>+<b>, "
                 "imu_only; else the setup's config.method");
  app.add_option("--encoding", encoding, "json or msgpack (asked for in the hello)")
      ->check(CLI::IsMember({"json", "msgpack"}));
  CLI11_PARSE(app, argc, argv);
  tofu::harness::HostedBuiltinEstimator estimator(method);
  return tofu::interface::ServeEstimator(estimator, STDIN_FILENO, STDOUT_FILENO,
                                         encoding == "msgpack" ? tofu::interface::Encoding::kMsgpack
                                                               : tofu::interface::Encoding::kJson);
}
