#pragma once
// Users' estimators and controllers behind tofu::api's classes: a process client speaking
// the lockstep protocol (docs/INTERFACE.md) over its standard streams, or a C++ plug-in
// loaded with dlopen. The run loop, `tofu estimate` and the corpora hold them as
// api::Estimator / api::Controller like tofu's own.

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "tofu/api.h"

namespace tofu::interface {

/// A client failed: it could not start, exited early, did not answer within its deadline,
/// sent a malformed message, a non-finite number, a time that went backwards, or spoke
/// another version. what() names the client, the message (type and seq) and the offending
/// field with the expected form; stderr_tail() is the client's last standard-error lines.
class ClientError : public std::runtime_error {
 public:
  ClientError(const std::string& message, std::vector<std::string> stderr_tail = {})
      : std::runtime_error(message), stderr_tail_(std::move(stderr_tail)) {}
  const std::vector<std::string>& stderr_tail() const { return stderr_tail_; }

 private:
  std::vector<std::string> stderr_tail_;
};

/// A client's failure as tofu tells it: `what`, then the last lines of its standard error
/// (at most 20), indented under "last lines of <name>'s standard error:".
std::string ClientFailureWithStderr(const std::string& what, const std::string& name,
                                    const std::vector<std::string>& stderr_tail);

/// A scenario's `external:` entry.
struct ProcessClientConfig {
  std::string name;                  ///< "external:<key>": in messages and errors
  std::vector<std::string> command;  ///< argv; command[0] looked up on PATH if no '/'
  std::filesystem::path working_dir; ///< the client runs here (the scenario's directory)
  double timeout_s = 10.0;           ///< deadline for each answer
  /// Open loop: measurements sent ahead of the answers read (1 = strict lockstep).
  std::size_t max_in_flight = 256;
};

/// An estimator in another process. Add() sends a measurement and appends the estimates
/// of every answer that has arrived so far, in order; Drain() waits for every answer still
/// outstanding (the closed loop calls it before each control tick). The estimates of
/// each answer are appended as a whole and in seq order, so the sequence of estimates is
/// the same whatever max_in_flight and the client's speed. Throws ClientError.
class ProcessEstimator : public api::Estimator {
 public:
  explicit ProcessEstimator(ProcessClientConfig config);
  ~ProcessEstimator() override;  ///< kills the client (and its process group) if alive
  void Start(const api::EstimatorSetup& setup) override;
  void Add(const api::Measurement& measurement, std::vector<api::Estimate>* out) override;
  void Finish(std::vector<api::Estimate>* out) override;
  std::string ReportJson() const override;
  void Drain(std::vector<api::Estimate>* out);
  /// The client's last standard-error lines (at most 20).
  std::vector<std::string> stderr_tail() const;
  /// Ends the client now (a failure tofu found in what it said) and returns its last
  /// standard-error lines, read to the end.
  std::vector<std::string> End();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// A controller in another process: every Compute waits for its answer.
class ProcessController : public api::Controller {
 public:
  explicit ProcessController(ProcessClientConfig config);
  ~ProcessController() override;
  void Start(const api::ControllerSetup& setup) override;
  api::ControlCommand Compute(const api::ControlState& state,
                              const api::ControlReference& reference) override;
  /// Sends finish and waits for the client to exit (the destructor kills it otherwise).
  void Finish();
  std::vector<std::string> stderr_tail() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// A loaded plug-in library (include/tofu/plugin.h). Open refuses a library that cannot
/// be loaded, lacks tofu_plugin_api_version, or reports another TOFU_API_VERSION (both
/// versions in the message), with a ClientError naming the library path.
class PluginLibrary : public std::enable_shared_from_this<PluginLibrary> {
 public:
  static std::shared_ptr<PluginLibrary> Open(const std::filesystem::path& library);
  ~PluginLibrary();
  /// A new estimator or controller of that name; the library stays loaded while it
  /// lives. Throws ClientError when the library makes none of that name (or none at all).
  std::unique_ptr<api::Estimator> CreateEstimator(const std::string& name);
  std::unique_ptr<api::Controller> CreateController(const std::string& name);
  const std::filesystem::path& path() const { return path_; }

 private:
  PluginLibrary() = default;
  std::filesystem::path path_;
  void* handle_ = nullptr;
};

}  // namespace tofu::interface
