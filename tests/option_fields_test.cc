// Options validate themselves (core/option_fields.h): every sim options struct's defaults
// are valid; every limit of every field table rejects a value just outside it, with a
// message that starts with the field's key; NaN is rejected everywhere; the models'
// constructors refuse invalid options. The tables are walked generically, so a field
// added with a limit is tested by the line that declares it.
#include <gtest/gtest.h>

#include <cctype>
#include <cmath>
#include <limits>
#include <set>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <variant>

#include "core/lidar_beam_pattern.h"
#include "core/option_fields.h"
#include "core/units.h"
#include "replay/estimation_config.h"
#include "sim/controller.h"
#include "sim/gnss.h"
#include "sim/imu.h"
#include "sim/lidar_odometry.h"
#include "sim/min_snap.h"
#include "sim/total_station.h"
#include "sim/vio.h"
#include "sim/wind.h"
#include "sim/world.h"

namespace tofu {
namespace {

using core::FieldFormat;
using core::NumberRule;

// A value just outside a bound, in the member's units (radians for fields written in
// degrees): below min (or at it when exclusive), above max (or at it when exclusive).
double Below(const NumberRule& rule, double factor) {
  const double min = *rule.min * factor;
  return rule.min_exclusive ? min : min - std::max(1e-6, std::abs(min) * 1e-6);
}
double Above(const NumberRule& rule, double factor) {
  const double max = *rule.max * factor;
  return rule.max_exclusive ? max : max + std::max(1e-6, std::abs(max) * 1e-6);
}

// Writes `value` into the member (every component of vectors and pairs); false when the
// member holds no number (flags, names, optional attitudes).
template <typename Options>
bool SetNumber(Options& options, const typename core::OptionField<Options>::Member& member,
               double value) {
  return std::visit(
      [&](auto pointer) {
        if constexpr (std::is_same_v<decltype(pointer), core::ChoiceMember<Options>>) {
          return false;
        } else {
        using T = std::remove_reference_t<decltype(options.*pointer)>;
        if constexpr (std::is_same_v<T, double> || std::is_same_v<T, std::optional<double>>) {
          options.*pointer = value;
          return true;
        } else if constexpr (std::is_same_v<T, Eigen::Vector3d>) {
          (options.*pointer)(1) = value;
          return true;
        } else if constexpr (std::is_same_v<T, std::optional<Eigen::Vector3d>>) {
          options.*pointer = Eigen::Vector3d(0.0, value, 0.0);
          return true;
        } else if constexpr (std::is_same_v<T, std::array<double, 2>>) {
          (options.*pointer)[1] = value;
          return true;
        } else {
          return false;
        }
        }
      },
      member);
}

template <typename Options>
std::string Why(const Options& options) {
  std::string why;
  EXPECT_FALSE(options.IsValid(&why));
  return why;
}

template <typename Options>
class OptionFieldsTest : public ::testing::Test {};

using OptionTypes =
    ::testing::Types<core::LidarBeamPattern, sim::ImuOptions, sim::VioOptions,
                     sim::LidarOdometryOptions,
                     sim::TotalStationOptions, sim::GnssOptions, sim::GnssFixErrorOptions,
                     sim::WindOptions, sim::ControllerOptions, replay::ConsensusConfig,
                     replay::EstimationConfig>;
TYPED_TEST_SUITE(OptionFieldsTest, OptionTypes);

TYPED_TEST(OptionFieldsTest, DefaultsAreValid) {
  std::string why;
  EXPECT_TRUE(TypeParam{}.IsValid(&why)) << why;
  EXPECT_TRUE(TypeParam{}.IsValid(nullptr));
}

// Keys are snake case starting with a lower-case letter; unit suffixes keep their SI case
// (rotor_thrust_coefficient_N_per_radps2).
TYPED_TEST(OptionFieldsTest, KeysAreUniqueSnakeCase) {
  std::set<std::string_view> keys;
  for (const auto& field : TypeParam::Fields()) {
    const std::string_view key = field.format.key;
    EXPECT_TRUE(keys.insert(key).second) << "key twice: " << key;
    ASSERT_FALSE(key.empty());
    EXPECT_TRUE(key.front() >= 'a' && key.front() <= 'z') << key;
    for (char c : key) {
      EXPECT_TRUE(std::isalnum(static_cast<unsigned char>(c)) || c == '_') << key;
    }
  }
}

TYPED_TEST(OptionFieldsTest, EveryNumberLimitRejectsAValueOutsideIt) {
  int limits_checked = 0;
  for (const auto& field : TypeParam::Fields()) {
    const FieldFormat& format = field.format;
    const double factor = format.degrees ? core::kRadPerDeg : 1.0;
    const std::string prefix = std::string(format.key) + ": ";
    if (format.rule.min) {
      TypeParam options;
      if (SetNumber(options, field.member, Below(format.rule, factor))) {
        EXPECT_EQ(Why(options).rfind(prefix, 0), 0u) << Why(options);
        ++limits_checked;
      }
    }
    if (format.rule.max) {
      TypeParam options;
      if (SetNumber(options, field.member, Above(format.rule, factor))) {
        EXPECT_EQ(Why(options).rfind(prefix, 0), 0u) << Why(options);
        ++limits_checked;
      }
    }
    {
      TypeParam options;
      if (SetNumber(options, field.member, std::numeric_limits<double>::quiet_NaN())) {
        EXPECT_EQ(Why(options).rfind(prefix, 0), 0u) << "NaN in " << format.key;
      }
      TypeParam infinite;
      if (SetNumber(infinite, field.member, std::numeric_limits<double>::infinity())) {
        EXPECT_EQ(Why(infinite).rfind(prefix, 0), 0u) << "inf in " << format.key;
      }
    }
  }
  // Every struct but the wind (a mean, a gust std and a direction) has bounded numbers.
  if (!std::is_same_v<TypeParam, sim::WindOptions>) {
    EXPECT_GT(limits_checked, 0);
  }
}

// SameFieldValue tells a changed field from the others and CopyFieldValue carries it over
// (what `tofu estimate --set profile=` keeps of a run's own keys), on the tables that use
// them. (GCC 12's -Warray-bounds misreads the attitude alternative on the sim's smaller
// structs, which never compare fields.)
template <typename Options>
class ComparedOptionFieldsTest : public ::testing::Test {};
using ComparedOptionTypes = ::testing::Types<replay::ConsensusConfig, replay::EstimationConfig>;
TYPED_TEST_SUITE(ComparedOptionFieldsTest, ComparedOptionTypes);

TYPED_TEST(ComparedOptionFieldsTest, AChangedFieldIsToldApartAndCopied) {
  int changed_fields = 0;
  for (const auto& changed : TypeParam::Fields()) {
    const TypeParam original;
    TypeParam other;
    if (!SetNumber(other, changed.member, 12345.0)) continue;
    ++changed_fields;
    for (const auto& field : TypeParam::Fields()) {
      EXPECT_EQ(core::SameFieldValue(original, other, field), &field != &changed)
          << changed.format.key << " changed, " << field.format.key << " compared";
    }
    TypeParam copy;
    core::CopyFieldValue(other, &copy, changed);
    for (const auto& field : TypeParam::Fields()) {
      EXPECT_TRUE(core::SameFieldValue(copy, other, field)) << field.format.key;
    }
  }
  EXPECT_GT(changed_fields, 0);
}

TYPED_TEST(OptionFieldsTest, EveryIntegerLimitRejectsAValueOutsideIt) {
  for (const auto& field : TypeParam::Fields()) {
    const auto* member = std::get_if<int TypeParam::*>(&field.member);
    if (member == nullptr) continue;
    const std::string prefix = std::string(field.format.key) + ": ";
    TypeParam below;
    below.*(*member) = field.format.min_integer - 1;
    EXPECT_EQ(Why(below).rfind(prefix, 0), 0u) << Why(below);
    TypeParam above;
    above.*(*member) = field.format.max_integer + 1;
    EXPECT_EQ(Why(above).rfind(prefix, 0), 0u) << Why(above);
  }
}

TYPED_TEST(OptionFieldsTest, ValuesAtTheInclusiveBoundsPass) {
  // A bound read from a file in degrees is converted as the value is: a value at the
  // bound must still pass after the conversion (NumberRule::Scaled).
  for (const auto& field : TypeParam::Fields()) {
    const FieldFormat& format = field.format;
    const double factor = format.degrees ? core::kRadPerDeg : 1.0;
    for (const std::optional<double>& bound :
         {format.rule.min_exclusive ? std::optional<double>() : format.rule.min,
          format.rule.max_exclusive ? std::optional<double>() : format.rule.max}) {
      if (!bound) continue;
      TypeParam options;
      if (!SetNumber(options, field.member, *bound * factor)) continue;
      // The table alone: a rule between fields (elevation_max_deg >= elevation_min_deg)
      // may refuse a bound that the field's own limit accepts.
      std::string why;
      EXPECT_TRUE(core::CheckOptionFields<TypeParam>(options, TypeParam::Fields(), &why))
          << why;
    }
  }
}

// ---- rules between fields ----

TEST(OptionFields, CrossFieldRulesNameTheirKey) {
  sim::VioOptions vio;
  vio.feature_max_depth_m = vio.feature_min_depth_m;
  EXPECT_EQ(Why(vio).rfind("feature_max_depth_m: ", 0), 0u) << Why(vio);

  sim::GnssOptions gnss;
  gnss.min_satellites_single = 8;
  gnss.min_satellites_float = 6;
  EXPECT_EQ(Why(gnss).rfind("min_satellites_float: ", 0), 0u) << Why(gnss);

  sim::GnssOptions nested;
  nested.rtk_float.std_horizontal_m = -1.0;
  EXPECT_EQ(Why(nested).rfind("rtk_float.std_horizontal_m: ", 0), 0u) << Why(nested);
}

// MinimumDerivativeOptions (integers only; the generic tests' number paths would be dead
// code GCC warns about): valid defaults, each integer limit refused with its key.
TEST(OptionFields, MinimumDerivativeOptionsRefuseIntegersOutsideTheirTable) {
  using Options = sim::min_snap::MinimumDerivativeOptions;
  std::string why;
  EXPECT_TRUE(Options{}.IsValid(&why)) << why;
  for (const auto& field : Options::Fields()) {
    const auto* member = std::get_if<int Options::*>(&field.member);
    ASSERT_NE(member, nullptr) << field.format.key;
    const std::string prefix = std::string(field.format.key) + ": ";
    Options below;
    below.*(*member) = field.format.min_integer - 1;
    EXPECT_EQ(Why(below).rfind(prefix, 0), 0u) << Why(below);
    Options above;
    above.*(*member) = field.format.max_integer + 1;
    EXPECT_EQ(Why(above).rfind(prefix, 0), 0u) << Why(above);
  }
}

// sim::WorldOptions has no valid default (a world must be named): its table is checked here.
TEST(OptionFields, WorldOptionsNameTheBrokenField) {
  sim::WorldOptions world{.world = "indoor_arena"};
  std::string why;
  EXPECT_TRUE(world.IsValid(&why)) << why;
  EXPECT_EQ(Why(sim::WorldOptions{}).rfind("world: expected a name", 0), 0u)
      << Why(sim::WorldOptions{});

  sim::WorldOptions rate = world;
  rate.physics_rate_hz = 50.0;
  EXPECT_EQ(Why(rate), "rate_hz: expected a number in [100, 10000] (Hz), got 50");
  sim::WorldOptions robot = world;
  robot.robot = "OMAV";
  EXPECT_EQ(Why(robot).rfind("robot: expected a name", 0), 0u) << Why(robot);
  sim::WorldOptions horizon = world;
  horizon.distance_horizon_m = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(Why(horizon).rfind("distance_horizon_m: expected a finite number", 0), 0u)
      << Why(horizon);
}

// ---- constructors validate ----

const sim::World& Arena() {
  static const sim::World world(sim::WorldOptions{.world = "indoor_arena"});
  return world;
}

TEST(OptionFields, ModelConstructorsRefuseInvalidOptions) {
  sim::ImuOptions imu;
  imu.rate_hz = -200.0;
  try {
    sim::ImuModel model("imu", imu, Arena(), 1);
    FAIL() << "an IMU at -200 Hz was built";
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()).rfind("IMU 'imu': rate_hz: ", 0), 0u) << e.what();
  }
  sim::VioOptions vio;
  vio.feature_max_depth_m = 0.5 * vio.feature_min_depth_m;
  EXPECT_THROW(sim::VioModel("vio", vio, Arena(), 1), std::invalid_argument);
  sim::GnssOptions gnss;
  gnss.rtk_fixed.correlated_fraction = 1.5;
  EXPECT_THROW(sim::GnssModel("gnss", gnss, Arena(), 1), std::invalid_argument);
  sim::TotalStationOptions total_station;
  total_station.rate_hz = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(sim::TotalStationModel("ts", total_station, Arena(), 1), std::invalid_argument);
  sim::LidarOdometryOptions lidar;
  lidar.max_range_m = 0.5 * lidar.min_range_m;
  EXPECT_THROW(sim::LidarOdometryModel("lidar", lidar, Arena(), 1), std::invalid_argument);
  sim::ControllerOptions controller;
  controller.rate_hz = -1.0;
  EXPECT_THROW(sim::GeometricController(controller, sim::RigidBodyParams{}),
               std::invalid_argument);
}

// ---- NumberRule ----

TEST(NumberRule, BoundsAndTheirText) {
  const NumberRule between = NumberRule::Between(100.0, 10000.0, "Hz");
  EXPECT_TRUE(between.Accepts(100.0));
  EXPECT_TRUE(between.Accepts(10000.0));
  EXPECT_FALSE(between.Accepts(99.999));
  EXPECT_EQ(between.Describe(), " in [100, 10000] (Hz)");
  const NumberRule positive = NumberRule::Positive("m");
  EXPECT_FALSE(positive.Accepts(0.0));
  EXPECT_TRUE(positive.Accepts(1e-300));
  EXPECT_EQ(positive.Describe(), " > 0 (m)");
  const NumberRule radians = NumberRule::Between(0.0, 89.0, "deg").Scaled(core::kRadPerDeg);
  EXPECT_TRUE(radians.Accepts(89.0 * core::kRadPerDeg));
  EXPECT_FALSE(radians.Accepts(89.001 * core::kRadPerDeg));
}

TEST(FormatDouble, ShortestTextThatParsesBack) {
  for (double value : {0.1, 1.0 / 3.0, 1e-300, -2.5, 6.02214076e23, 100.0}) {
    EXPECT_EQ(std::stod(core::FormatDouble(value)), value) << core::FormatDouble(value);
  }
  EXPECT_EQ(core::FormatDouble(0.1), "0.1");
  EXPECT_EQ(core::FormatDouble(100.0), "100");
}

}  // namespace
}  // namespace tofu
