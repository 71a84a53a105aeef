#pragma once
// Private to harness: users' estimators and controllers in a scenario (docs/INTERFACE.md):
//
//   external:                       process clients, by key ("external:<key>")
//     my_ekf:
//       command: [/usr/bin/python3, ekf.py]   argv (required, non-empty)
//       working_dir: .              where it runs (default: the scenario's directory)
//       timeout_s: 10               deadline of each answer (0.01 .. 3600)
//       config: {any: map}          handed to the client as JSON
//   plugins:                        C++ plug-ins, by key ("plugin:<key>")
//     cf:
//       library: build/libcf.so     the shared library (required)
//       config: {any: map}
//
// `${NAME}` and `${NAME:-default}` in command words, working_dir and library take the
// environment's value (a CI's build directory). Relative paths are resolved against the
// scenario's directory when read, so the resolved scenario (a run directory's
// scenario.yaml) names the same files from anywhere.

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "harness/yaml_reader.h"
#include "replay/estimation_config.h"

namespace tofu::harness {

/// Reads `external:` and `plugins:` (either may be absent). `scenario_file`: the file the
/// scenario was read from (its directory resolves relative paths).
std::vector<replay::ClientSpec> ReadClients(const std::optional<YamlValue>& external,
                                            const std::optional<YamlValue>& plugins,
                                            const std::string& scenario_file);

/// Writes them back (nothing when there is none), paths absolute.
void EmitClients(YAML::Emitter& out, const std::vector<replay::ClientSpec>& clients);

/// What can be known of the clients before anything flies, without starting one: each
/// process client's command resolves to an executable file in an existing working
/// directory (interface::ResolveCommand), each plug-in library loads and speaks this
/// tofu's API version (interface::PluginLibrary::Open, then unloaded). Throws
/// core::InputError at `where("external.<key>")` / `where("plugins.<key>")` naming the
/// client and the problem.
void CheckClientsResolve(const std::vector<replay::ClientSpec>& clients,
                         const std::function<core::SourceLocation(const std::string&)>& where);

/// A client name ("external:<key>", "plugin:<key>") among `clients`, or nullptr.
const replay::ClientSpec* FindClient(const std::vector<replay::ClientSpec>& clients,
                                     const std::string& name);

}  // namespace tofu::harness
