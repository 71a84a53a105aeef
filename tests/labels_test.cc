// SensorHealth (harness/labels.h): which sensors the ground-truth labels call healthy, the
// timeline the `oracle` method fuses by.
#include "harness/labels.h"

#include <gtest/gtest.h>

namespace tofu::harness {
namespace {

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

}  // namespace
}  // namespace tofu::harness
