#include "harness/client_config.h"

#include <charconv>
#include <cstdlib>
#include <filesystem>
#include <optional>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "interface/child_process.h"
#include "interface/client.h"

namespace tofu::harness {
namespace {

namespace fs = std::filesystem;
using replay::ClientSpec;

// A YAML scalar as JSON: plain (unquoted) true/false, null and numbers keep their type;
// everything else, and any quoted scalar, is a string.
nlohmann::json ScalarToJson(const YAML::Node& node) {
  const std::string& text = node.Scalar();
  if (node.Tag() == "!") return text;  // quoted
  if (text == "true" || text == "True") return true;
  if (text == "false" || text == "False") return false;
  if (text == "null" || text == "~" || text.empty()) return nullptr;
  long long integer = 0;
  if (auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), integer);
      ec == std::errc() && end == text.data() + text.size()) {
    return integer;
  }
  char* end = nullptr;
  const double number = std::strtod(text.c_str(), &end);
  if (end == text.c_str() + text.size() && !text.empty()) return number;
  return text;
}

nlohmann::json YamlToJson(const YAML::Node& node) {
  switch (node.Type()) {
    case YAML::NodeType::Map: {
      nlohmann::json object = nlohmann::json::object();
      for (const auto& entry : node) object[entry.first.as<std::string>()] = YamlToJson(entry.second);
      return object;
    }
    case YAML::NodeType::Sequence: {
      nlohmann::json array = nlohmann::json::array();
      for (const auto& item : node) array.push_back(YamlToJson(item));
      return array;
    }
    case YAML::NodeType::Scalar:
      return ScalarToJson(node);
    default:
      return nullptr;
  }
}

void EmitJson(YAML::Emitter& out, const nlohmann::json& value) {
  if (value.is_object()) {
    out << YAML::BeginMap;
    for (const auto& [key, item] : value.items()) {
      out << YAML::Key << key << YAML::Value;
      EmitJson(out, item);
    }
    out << YAML::EndMap;
  } else if (value.is_array()) {
    out << YAML::Flow << YAML::BeginSeq;
    for (const auto& item : value) EmitJson(out, item);
    out << YAML::EndSeq;
  } else if (value.is_string()) {
    out << YAML::DoubleQuoted << value.get<std::string>();
  } else if (value.is_null()) {
    out << YAML::Null;
  } else {
    out << value.dump();  // numbers (round-trip form) and booleans as JSON writes them
  }
}

// `${NAME}` and `${NAME:-default}` in a path or a command word, from the environment (a
// CI's build directory, a user's install prefix): the scenario stays the same file.
std::string ExpandEnvironment(const YamlValue& where, const std::string& text) {
  std::string out;
  std::size_t i = 0;
  while (i < text.size()) {
    const std::size_t open = text.find("${", i);
    if (open == std::string::npos) break;
    const std::size_t close = text.find('}', open);
    if (close == std::string::npos) where.FailExpected("a closing '}' after '${'");
    out += text.substr(i, open - i);
    std::string name = text.substr(open + 2, close - open - 2);
    std::optional<std::string> fallback;
    if (const std::size_t dash = name.find(":-"); dash != std::string::npos) {
      fallback = name.substr(dash + 2);
      name.resize(dash);
    }
    if (name.empty() || name.find_first_not_of("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz"
                                               "0123456789_") != std::string::npos) {
      where.FailExpected("${NAME} or ${NAME:-default} with NAME of letters, digits and _");
    }
    const char* value = std::getenv(name.c_str());
    if (value == nullptr || *value == '\0') {
      if (!fallback) {
        where.Fail(fmt::format("environment variable {} is not set (write ${{{}:-default}} for a "
                               "default)", name, name));
      }
      out += *fallback;
    } else {
      out += value;
    }
    i = close + 1;
  }
  return out + text.substr(i);
}

std::string Absolute(const fs::path& base, const std::string& path) {
  const fs::path p(path);
  return (p.is_absolute() ? p : base / p).lexically_normal().string();
}

std::string ReadConfig(YamlMap& map) {
  const auto config = map.Optional("config");
  if (!config) return "{}";
  if (!config->node().IsMap() && !config->IsNull()) config->FailExpected("a map (any keys)");
  if (config->IsNull()) return "{}";
  try {
    return YamlToJson(config->node()).dump();
  } catch (const nlohmann::json::type_error&) {
    // The client's config travels as JSON text, which holds UTF-8 only (type_error 316).
    config->Fail("a key or string of it is not valid UTF-8 text (the config reaches the client "
                 "as JSON, which holds UTF-8 only)");
  }
}

ClientSpec ReadProcessClient(const std::string& key, const YamlValue& value, const fs::path& base) {
  ClientSpec c;
  c.kind = ClientSpec::Kind::kProcess;
  c.key = key;
  YamlMap map = value.Map({"command", "working_dir", "timeout_s", "config"});
  const YamlValue command = map.Required("command");
  for (const YamlValue& item : command.List(/*non_empty=*/true)) {
    c.command.push_back(ExpandEnvironment(item, item.String()));
  }
  if (c.command.front().empty()) command.FailExpected("a program as the command's first word");
  c.working_dir = base.lexically_normal().string();
  if (const auto dir = map.Optional("working_dir")) {
    c.working_dir = Absolute(base, ExpandEnvironment(*dir, dir->String()));
  }
  if (const auto timeout = map.Optional("timeout_s")) {
    c.timeout_s = timeout->Number(NumberRule::Between(0.01, 3600.0, "s"));
  }
  c.config_json = ReadConfig(map);
  map.Finish();
  return c;
}

ClientSpec ReadPluginClient(const std::string& key, const YamlValue& value, const fs::path& base) {
  ClientSpec c;
  c.kind = ClientSpec::Kind::kPlugin;
  c.key = key;
  YamlMap map = value.Map({"library", "config"});
  const YamlValue library = map.Required("library");
  if (library.String().empty()) library.FailExpected("the path of a shared library");
  c.library = Absolute(base, ExpandEnvironment(library, library.String()));
  c.config_json = ReadConfig(map);
  map.Finish();
  return c;
}

}  // namespace

std::vector<ClientSpec> ReadClients(const std::optional<YamlValue>& external,
                                    const std::optional<YamlValue>& plugins,
                                    const std::string& scenario_file) {
  // The scenario's directory, absolute: a file named without one ("s.yaml") is in the
  // working directory, and the resolved scenario of a run directory must name it.
  std::error_code ec;
  const fs::path parent = fs::path(scenario_file).parent_path();
  const fs::path base = (parent.empty() ? fs::current_path(ec) : fs::absolute(parent, ec)).lexically_normal();
  if (ec) {
    throw core::InputError({scenario_file, 0, 0}, "external",
                           fmt::format("cannot resolve the scenario's directory: {}", ec.message()));
  }
  std::vector<ClientSpec> clients;
  if (external) {
    for (const auto& [key, value] : external->Entries()) {
      clients.push_back(ReadProcessClient(key, value, base));
    }
  }
  if (plugins) {
    for (const auto& [key, value] : plugins->Entries()) {
      clients.push_back(ReadPluginClient(key, value, base));
    }
  }
  return clients;
}

void EmitClients(YAML::Emitter& out, const std::vector<ClientSpec>& clients) {
  for (const ClientSpec::Kind kind : {ClientSpec::Kind::kProcess, ClientSpec::Kind::kPlugin}) {
    bool open = false;
    for (const ClientSpec& c : clients) {
      if (c.kind != kind) continue;
      if (!open) {
        out << YAML::Key << (kind == ClientSpec::Kind::kProcess ? "external" : "plugins")
            << YAML::Value << YAML::BeginMap;
        open = true;
      }
      out << YAML::Key << c.key << YAML::Value << YAML::BeginMap;
      if (kind == ClientSpec::Kind::kProcess) {
        out << YAML::Key << "command" << YAML::Value << YAML::Flow << YAML::BeginSeq;
        for (const std::string& word : c.command) out << YAML::DoubleQuoted << word;
        out << YAML::EndSeq;
        out << YAML::Key << "working_dir" << YAML::Value << YAML::DoubleQuoted << c.working_dir;
        out << YAML::Key << "timeout_s" << YAML::Value << nlohmann::json(c.timeout_s).dump();
      } else {
        out << YAML::Key << "library" << YAML::Value << YAML::DoubleQuoted << c.library;
      }
      out << YAML::Key << "config" << YAML::Value;
      EmitJson(out, nlohmann::json::parse(c.config_json));
      out << YAML::EndMap;
    }
    if (open) out << YAML::EndMap;
  }
}

const ClientSpec* FindClient(const std::vector<ClientSpec>& clients, const std::string& name) {
  for (const ClientSpec& c : clients) {
    if (c.Name() == name) return &c;
  }
  return nullptr;
}

void CheckClientsResolve(const std::vector<replay::ClientSpec>& clients,
                         const std::function<core::SourceLocation(const std::string&)>& where) {
  for (const replay::ClientSpec& client : clients) {
    if (client.kind == replay::ClientSpec::Kind::kProcess) {
      const std::string key = "external." + client.key;
      try {
        interface::ResolveCommand(client.command, client.working_dir);
      } catch (const std::runtime_error& e) {
        throw core::InputError(where(key), key + ".command",
                               fmt::format("{} cannot start: {}", client.Name(), e.what()));
      }
    } else {
      const std::string key = "plugins." + client.key;
      try {
        interface::PluginLibrary::Open(client.library);
      } catch (const std::exception& e) {
        throw core::InputError(where(key), key + ".library", e.what());
      }
    }
  }
}

}  // namespace tofu::harness
