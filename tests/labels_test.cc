// SensorHealth (replay/labels.h): which sensors the ground-truth labels call healthy, the
// timeline the `oracle` method fuses by; and the condition-fraction metric over labels.
#include "replay/labels.h"

#include "harness/evaluation.h"
#include "harness/metrics.h"
#include "harness/run.h"

#include <gtest/gtest.h>

namespace tofu::harness {
namespace {

using replay::LabelEvent;
using replay::SensorHealth;

LabelEvent Label(core::Time t_ns, const std::string& sensor, const std::string& label,
                 const std::string& source, bool active) {
  return LabelEvent{t_ns, sensor, label, source, active};
}

TEST(SensorHealth, AnyActiveFaultOrConditionMakesASensorUnhealthy) {
  SensorHealth health;
  health.Add(Label(10, "vio", "divergence", "fault", true));
  health.Add(Label(20, "vio", "divergence", "fault", false));
  health.Add(Label(15, "vio", "feature_starved", "condition", true));
  health.Add(Label(25, "vio", "feature_starved", "condition", false));
  EXPECT_TRUE(health.Healthy("vio", 9));
  EXPECT_FALSE(health.Healthy("vio", 10));  // a transition counts from its time on
  EXPECT_EQ(health.ActiveLabels("vio", 16), "feature_starved+divergence");
  EXPECT_FALSE(health.Healthy("vio", 20));  // the condition still holds
  EXPECT_TRUE(health.Healthy("vio", 25));
  EXPECT_TRUE(health.Healthy("leica", 16));  // no label at all: healthy
}

TEST(SensorHealth, LabelsAddedLateAndQueriesBackInTimeAreAnsweredFromTheTimeline) {
  SensorHealth health;
  health.Add(Label(100, "gnss", "no_fix", "condition", true));
  EXPECT_FALSE(health.Healthy("gnss", 150));
  // The run loop learns the end of a condition as it flies: added after the queries.
  health.Add(Label(200, "gnss", "no_fix", "condition", false));
  EXPECT_FALSE(health.Healthy("gnss", 199));
  EXPECT_TRUE(health.Healthy("gnss", 200));
  // Out of order: a label for a time already passed replays the timeline.
  health.Add(Label(50, "gnss", "multipath", "condition", true));
  EXPECT_FALSE(health.Healthy("gnss", 300));
  EXPECT_TRUE(health.Healthy("gnss", 40));  // back in time
  EXPECT_FALSE(health.Healthy("gnss", 60));
}

// Two overlapping faults of one kind on one sensor (divergence 8-14 s and 10-16 s give
// labels start 8, start 10, end 14, end 16): unhealthy until the last one ends.
TEST(SensorHealth, OverlappingFaultsOfOneKindLastUntilTheLastEnds) {
  SensorHealth health;
  health.Add(Label(8, "lio", "divergence", "fault", true));
  health.Add(Label(10, "lio", "divergence", "fault", true));
  health.Add(Label(14, "lio", "divergence", "fault", false));
  health.Add(Label(16, "lio", "divergence", "fault", false));
  EXPECT_FALSE(health.Healthy("lio", 15));
  EXPECT_TRUE(health.Healthy("lio", 16));
  // An end without a start (a fault begun before the log) is ignored, not negative.
  health.Add(Label(20, "lio", "jump", "fault", false));
  health.Add(Label(22, "lio", "jump", "fault", true));
  EXPECT_TRUE(health.Healthy("lio", 21));
  EXPECT_FALSE(health.Healthy("lio", 22));
}

TEST(ConditionFraction, AUnionCountsTimeWhenAnyOfItsConditionsIsActiveOnce) {
  // 10 s at 100 Hz; GNSS: single fix 2-5 s, no fix 4-7 s (overlapping 4-5 s), float 8-9 s.
  RunRecord record;
  record.scenario.physics.rate_hz = 100.0;
  record.physics_steps = 1000;
  record.sensors.emplace_back();
  record.sensors.back().name = "gnss";
  const core::Time s = 1'000'000'000;
  record.labels = {Label(2 * s, "gnss", "single_fix", "condition", true),
                   Label(4 * s, "gnss", "no_fix", "condition", true),
                   Label(5 * s, "gnss", "single_fix", "condition", false),
                   Label(6 * s, "vio", "no_fix", "condition", true),  // another sensor
                   Label(7 * s, "gnss", "no_fix", "condition", false),
                   Label(8 * s, "gnss", "float_fix", "condition", true),
                   Label(8 * s, "gnss", "no_fix", "fault", true)};  // a fault, not a condition
  const auto fraction = [&](const std::string& metric) {
    return MetricValue(record, metric, std::nullopt).value();
  };
  EXPECT_NEAR(fraction("sensors.gnss.condition.single_fix"), 0.3, 1e-12);
  EXPECT_NEAR(fraction("sensors.gnss.condition.no_fix"), 0.3, 1e-12);
  EXPECT_NEAR(fraction("sensors.gnss.condition.single_fix+no_fix"), 0.5, 1e-12);
  // float_fix stays active to the end of the run: 8-10 s.
  EXPECT_NEAR(fraction("sensors.gnss.condition.single_fix+no_fix+float_fix"), 0.7, 1e-12);
  EXPECT_NEAR(MetricValue(record, "sensors.gnss.condition.no_fix+single_fix",
                          std::make_pair(4.5, 6.5)).value(),
              1.0, 1e-12);
  EXPECT_FALSE(FindMetric("sensors.gnss.condition.no_fix+sunshine"));
  EXPECT_FALSE(FindMetric("sensors.gnss.condition.no_fix+"));
}

}  // namespace
}  // namespace tofu::harness
