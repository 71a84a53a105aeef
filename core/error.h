#pragma once
// Error types that cross module boundaries. Bad user input (scenario YAML, CSV, CLI)
// is an InputError: the CLI prints it and exits with code 2, leaving no output behind.
// A simulation that cannot go on (MuJoCo's bad-state warnings, a diverged run) is a
// SimulationError. An output that cannot be written is an IoError. Internal invariants
// are asserts, not exceptions.

#include <stdexcept>
#include <string>

namespace tofu::core {

/// Where in a user's file a problem sits; line and column are 1-based, 0 if unknown.
struct SourceLocation {
  std::string file;
  int line = 0;
  int column = 0;
};

/// Bad user input. what() reads "file:line:column: key 'a.b[2].c': message".
class InputError : public std::runtime_error {
 public:
  InputError(SourceLocation location, std::string key_path, std::string message);

  const SourceLocation& location() const { return location_; }
  const std::string& key_path() const { return key_path_; }
  const std::string& message() const { return message_; }

 private:
  SourceLocation location_;
  std::string key_path_;
  std::string message_;
};

/// The simulation reached a state it cannot continue from.
class SimulationError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// An output could not be written (disk full, no permission, a path that is a file): not
/// the user's input and not the simulation. what() names the path.
class IoError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Process exit codes of the CLI, one meaning each.
enum ExitCode : int {
  kExitOk = 0,
  kExitExpectationFailed = 1,
  kExitBadInput = 2,
  kExitSimulationError = 3,  ///< the simulation itself failed (or tofu did)
  kExitIoError = 4,
  /// A user's estimator or controller failed (docs/INTERFACE.md); the simulation and the
  /// other methods were sound and are scored.
  kExitClientFailed = 5,
};

}  // namespace tofu::core
