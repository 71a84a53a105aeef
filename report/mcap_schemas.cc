#include "report/mcap_schemas.h"

#include <map>
#include <stdexcept>

#include <nlohmann/json.hpp>

namespace tofu::report {
namespace {

using Json = nlohmann::ordered_json;

// Building blocks, each a JSON Schema object.
Json Object(const std::string& title, Json properties, const std::string& description = "") {
  Json required = Json::array();
  for (const auto& item : properties.items()) required.push_back(item.key());
  Json s = {{"title", title}, {"type", "object"}};
  if (!description.empty()) s["description"] = description;
  s["properties"] = std::move(properties);
  s["required"] = std::move(required);
  return s;
}

// A number, or null where the value was not finite (a NaN sample of a faulted stream).
Json Number(const std::string& description) {
  return {{"type", Json::array({"number", "null"})}, {"description", description}};
}

Json Time(const std::string& description) {
  Json s = Object("time", {{"sec", {{"type", "integer"}, {"minimum", 0}}},
                           {"nsec", {{"type", "integer"}, {"minimum", 0}, {"maximum", 999999999}}}});
  s["description"] = description;
  return s;
}

Json Vector3(const std::string& description) {
  Json s = Object("foxglove.Vector3", {{"x", Number("x")}, {"y", Number("y")}, {"z", Number("z")}});
  s["description"] = description;
  return s;
}

Json Quaternion(const std::string& description) {
  Json s = Object("foxglove.Quaternion",
                  {{"x", Number("x")}, {"y", Number("y")}, {"z", Number("z")}, {"w", Number("w")}});
  s["description"] = description;
  return s;
}

Json Pose(const std::string& description) {
  Json s = Object("foxglove.Pose", {{"position", Vector3("position")},
                                    {"orientation", Quaternion("orientation")}});
  s["description"] = description;
  return s;
}

Json Strings(const std::string& description) {
  return {{"type", "array"}, {"items", {{"type", "string"}}}, {"description", description}};
}

Json Numbers(const std::string& description, int count) {
  return {{"type", "array"},
          {"items", {{"type", Json::array({"number", "null"})}}},
          {"minItems", count},
          {"maxItems", count},
          {"description", description}};
}

Json String(const std::string& description) {
  return {{"type", "string"}, {"description", description}};
}

Json Color() {
  return Object("foxglove.Color", {{"r", Number("red 0-1")}, {"g", Number("green 0-1")},
                                   {"b", Number("blue 0-1")}, {"a", Number("alpha 0-1")}});
}

Json Primitive(const std::string& title, bool cylinder) {
  Json properties = {{"pose", Pose("centre and orientation")},
                     {"size", Vector3(cylinder ? "diameters in x and y, height in z [m]"
                                               : "extent along each axis [m]")}};
  if (cylinder) {
    properties["bottom_scale"] = Number("1: a cylinder");
    properties["top_scale"] = Number("1: a cylinder");
  }
  properties["color"] = Color();
  return Object(title, properties);
}

Json EmptyList() { return {{"type", "array"}, {"maxItems", 0}}; }

// Long by design: one table of every topic's JSON schema, read top to bottom like docs/MCAP.md.
std::map<std::string, std::string> MakeSchemas() {
  std::map<std::string, Json> s;
  const Json timestamp = Time("time of validity since the run's start");
  const Json labels = Strings("active labels of the sample (README, 'Run directory')");

  s["foxglove.PoseInFrame"] =
      Object("foxglove.PoseInFrame",
             {{"timestamp", timestamp}, {"frame_id", String("frame of the pose")}, {"pose", Pose("pose")}},
             "A timestamped pose in a frame");
  s["foxglove.FrameTransform"] =
      Object("foxglove.FrameTransform",
             {{"timestamp", timestamp},
              {"parent_frame_id", String("parent frame")},
              {"child_frame_id", String("child frame")},
              {"translation", Vector3("child origin in parent [m]")},
              {"rotation", Quaternion("child orientation in parent")}},
             "The transform from a parent to a child frame");
  s["foxglove.Log"] = Object(
      "foxglove.Log",
      {{"timestamp", timestamp},
       {"level", {{"type", "integer"}, {"enum", {0, 1, 2, 3, 4, 5}}, {"description", "foxglove.LogLevel"}}},
       {"message", String("text")},
       {"name", String("the sensor or method concerned")},
       {"file", String("the run file it comes from")},
       {"line", {{"type", "integer"}, {"minimum", 0}}}},
      "A log message");
  Json entity = Object("foxglove.SceneEntity",
                       {{"timestamp", timestamp},
                        {"frame_id", String("frame")},
                        {"id", String("entity id")},
                        {"lifetime", Time("0: forever")},
                        {"frame_locked", {{"type", "boolean"}}},
                        {"metadata", EmptyList()},
                        {"arrows", EmptyList()},
                        {"cubes", {{"type", "array"}, {"items", Primitive("foxglove.CubePrimitive", false)}}},
                        {"spheres", {{"type", "array"}, {"items", Primitive("foxglove.SpherePrimitive", false)}}},
                        {"cylinders", {{"type", "array"}, {"items", Primitive("foxglove.CylinderPrimitive", true)}}},
                        {"lines", EmptyList()},
                        {"triangles", EmptyList()},
                        {"texts", EmptyList()},
                        {"models", EmptyList()}});
  s["foxglove.SceneUpdate"] =
      Object("foxglove.SceneUpdate",
             {{"deletions", EmptyList()}, {"entities", {{"type", "array"}, {"items", entity}}}},
             "The world's geometry (frame world) and the robot's (frame base_link)");

  s["tofu.ImuSample"] =
      Object("tofu.ImuSample",
             {{"timestamp", timestamp},
              {"arrival", Time("when the sample reached its consumers")},
              {"conditions", labels},
              {"faults", labels},
              {"angular_velocity_radps", Vector3("w_RS_S: angular rate in the IMU frame [rad/s]")},
              {"linear_acceleration_mps2", Vector3("a_RS_S: specific force in the IMU frame [m/s^2]")}},
             "One row of sensors/<imu>.csv");
  Json pose_measurement =
      Object("tofu.PoseMeasurement",
             {{"timestamp", timestamp},
              {"arrival", Time("when the sample reached its consumers")},
              {"conditions", labels},
              {"faults", labels},
              {"frame_id", String("<sensor>_reference: the sensor's reference frame S")},
              {"pose", Pose("T_Ss: the mount site s in S")},
              {"covariance", Numbers("6x6 row-major, of [delta_theta [rad]; delta_p [m]]", 36)}},
             "One row of sensors/<vio|lidar>.csv");
  pose_measurement["properties"]["linear_velocity_mps"] = Vector3("v_s in s [m/s]");
  pose_measurement["properties"]["angular_velocity_radps"] = Vector3("omega_s in s [rad/s]");
  pose_measurement["properties"]["twist_covariance"] = Numbers("6x6 row-major of [v; omega]", 36);
  s["tofu.PoseMeasurement"] = pose_measurement;
  s["tofu.PositionMeasurement"] =
      Object("tofu.PositionMeasurement",
             {{"timestamp", timestamp},
              {"arrival", Time("when the sample reached its consumers")},
              {"conditions", labels},
              {"faults", labels},
              {"frame_id", String("<sensor>_reference: the sensor's reference frame S")},
              {"position", Vector3("p_Ss [m]")},
              {"covariance", Numbers("3x3 row-major [m^2]", 9)}},
             "One row of sensors/<total_station|gnss>.csv");
  s["tofu.Estimate"] =
      Object("tofu.Estimate",
             {{"timestamp", timestamp},
              {"frame_id", String("L: the estimator's frame")},
              {"pose", Pose("T_LI: the IMU in L")},
              {"velocity_mps", Vector3("v_L")},
              {"accel_bias_mps2", Vector3("b_a")},
              {"gyro_bias_radps", Vector3("b_g")},
              {"position_std_m", Vector3("sqrt of the position covariance's diagonal (null: none)")},
              {"valid", {{"type", "boolean"}}},
              {"fused", Strings("sensors fused")}},
             "One row of estimate_<method>.csv");
  s["tofu.EstimateError"] =
      Object("tofu.EstimateError",
             {{"timestamp", timestamp},
              {"position_error_m", Number("after the SE(3) alignment [m]")},
              {"rotation_error_deg", Number("[deg]")}},
             "One row of errors.csv");
  s["tofu.ConsensusDecision"] =
      Object("tofu.ConsensusDecision",
             {{"timestamp", timestamp},
              {"method", String("the consensus method")},
              {"fused", Strings("sensors fused")},
              {"excluded", Strings("sensors judged inconsistent")},
              {"unavailable", Strings("sensors without data or alignment")},
              {"reason", String("why")}},
             "One row of decisions.csv");
  Json entry = Object("tofu.ConsistencyEntry", {{"a", String("sensor")},
                                                {"b", String("sensor or 'local'")},
                                                {"metric", String("cvm, ...")},
                                                {"value", Number("null: unavailable")}});
  s["tofu.ConsistencyMatrix"] =
      Object("tofu.ConsistencyMatrix",
             {{"timestamp", timestamp}, {"entries", {{"type", "array"}, {"items", entry}}}},
             "The consistency values of one evaluation (consistency_<method>.csv)");

  std::map<std::string, std::string> text;
  for (auto& [name, schema] : s) {
    Json full = {{"$schema", "https://json-schema.org/draft/2020-12/schema"}};
    full.update(schema);
    text[name] = full.dump();
  }
  return text;
}

}  // namespace

const std::string& JsonSchemaText(const std::string& name) {
  static const std::map<std::string, std::string> schemas = MakeSchemas();
  return schemas.at(name);
}

}  // namespace tofu::report
