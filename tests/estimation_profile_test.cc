// The `estimation:` block through its option tables (replay/estimation_config.h): each
// profile's values, a key over its profile, the rules between fields (each consistency
// metric on its own threshold scale), the resolved block that reproduces a configuration
// under any default, `tofu estimate --set` and the generated reference page.
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>
#include <string>
#include <type_traits>
#include <variant>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "harness/scenario.h"
#include "harness/scenario_reference.h"
#include "replay/estimation_config.h"
#include "test_support.h"

namespace tofu::harness {
namespace {

using estimator::ConsensusPolicy;
using estimator::ConsistencyMetric;
using estimator::PoseBetweenNoise;
using estimator::PositionFactors;
using replay::EstimationConfig;
using replay::EstimationProfile;

constexpr char kLabel[] = "inline.yaml";

// Line 13 holds the estimation block's first key (`estimation:` is line 12).
std::string WithEstimation(const std::string& block) {
  return std::string(R"yaml(name: profile_test
world: indoor_arena
duration_s: 10
trajectory:
  start: {position_m: [0, 0, 1]}
  segments:
    - hover: {duration_s: 1}
sensors:
  imu: {}
  vio: {}
  leica: {type: total_station}
estimation:
  methods: [consensus, oracle]
)yaml") + block;
}

EstimationConfig Parse(const std::string& block) {
  return *ParseScenario(WithEstimation(block), kLabel).estimation;
}

core::InputError Error(const std::string& block) {
  try {
    Parse(block);
  } catch (const core::InputError& e) {
    return e;
  }
  ADD_FAILURE() << "expected an InputError for:\n" << block;
  return core::InputError({}, "", "");
}

// Every field of an options table equal in both.
template <typename Options>
void ExpectSameFields(const Options& a, const Options& b) {
  for (const core::OptionField<Options>& field : Options::Fields()) {
    std::visit(
        [&](auto member) {
          if constexpr (std::is_same_v<decltype(member), core::ChoiceMember<Options>>) {
            EXPECT_EQ(member.get(a), member.get(b)) << field.format.key;
          } else if constexpr (requires { a.*member == b.*member; }) {
            EXPECT_EQ(a.*member, b.*member) << field.format.key;
          } else {
            ADD_FAILURE() << field.format.key << ": a member this test cannot compare";
          }
        },
        field.member);
  }
}

// Every option of two configurations (methods and clients aside): both tables and the
// consensus priority, which no table holds.
void ExpectSameOptions(const EstimationConfig& a, const EstimationConfig& b) {
  ExpectSameFields(a, b);
  ExpectSameFields(a.consensus, b.consensus);
  EXPECT_EQ(a.consensus.priority, b.consensus.priority);
}

// ---- each profile's values ----

// The paper's configuration as tofu reproduces it (Lanegger et al.: the CM metric at
// 0.1 m/s, one sensor of the most consistent pair, no robust loss, between factors).
TEST(EstimationProfile, PaperIsTheSeedPapersConfiguration) {
  const EstimationConfig c = Parse("  profile: paper\n");
  EXPECT_EQ(c.profile, EstimationProfile::kPaper);
  EXPECT_EQ(c.consensus.metric, ConsistencyMetric::kCm);
  EXPECT_EQ(c.consensus.threshold, 0.1);
  EXPECT_FALSE(c.consensus.leave_threshold.has_value());
  EXPECT_EQ(c.consensus.min_dwell_s, 0.0);
  EXPECT_EQ(c.consensus.policy, ConsensusPolicy::kPairMember);
  EXPECT_TRUE(c.consensus.return_to_priority);
  EXPECT_EQ(c.consensus.window_s, 1.0);
  EXPECT_EQ(c.consensus.rate_hz, 10.0);
  EXPECT_EQ(c.consensus.bias_window_s, 0.0);
  EXPECT_EQ(c.huber_delta, 0.0);
  EXPECT_EQ(c.position_factors, PositionFactors::kBetween);
  EXPECT_FALSE(c.leave_out_degenerate_directions);
  EXPECT_EQ(c.pose_between_noise, PoseBetweenNoise::kConstant);
  EXPECT_EQ(c.alignment_level_prior_deg, 0.0);
  EXPECT_EQ(EstimationConfig::DefaultThreshold(EstimationProfile::kPaper, ConsistencyMetric::kNis),
            3.0);
}

// The measured choice, stated: the paper's with the threshold and Huber loss the shipped
// scenarios used, pose streams weighted by their own noise and the bias test.
TEST(EstimationProfile, RecommendedIsThePapersWithTheMeasuredChanges) {
  const EstimationConfig c = Parse("  profile: recommended\n");
  EXPECT_EQ(c.profile, EstimationProfile::kRecommended);
  EXPECT_EQ(c.consensus.metric, ConsistencyMetric::kCm);
  EXPECT_EQ(c.consensus.threshold, 0.3);
  EXPECT_EQ(c.huber_delta, 3.0);
  EXPECT_EQ(c.pose_between_noise, PoseBetweenNoise::kWhiteAndDrift);
  EXPECT_EQ(c.consensus.bias_window_s, 10.0);
  EstimationConfig rest = c;
  rest.consensus.threshold = 0.1;
  rest.huber_delta = 0.0;
  rest.pose_between_noise = PoseBetweenNoise::kConstant;
  rest.consensus.bias_window_s = 0.0;
  rest.profile = EstimationProfile::kPaper;
  ExpectSameOptions(rest, Parse("  profile: paper\n"));
}

TEST(EstimationProfile, ABlockWithoutAProfileGetsTheDefaultProfile) {
  const EstimationConfig c = Parse("");
  EXPECT_EQ(c.profile, EstimationConfig::kDefaultProfile);
  ExpectSameOptions(c, Parse(std::string("  profile: ") +
                             std::string(replay::EstimationProfileName(
                                 EstimationConfig::kDefaultProfile)) +
                             "\n"));
}

TEST(EstimationProfile, AKeyOverridesItsProfilesValueAndNothingElse) {
  for (const EstimationProfile p : replay::kEstimationProfiles) {
    const std::string profile(replay::EstimationProfileName(p));
    const EstimationConfig base = Parse("  profile: " + profile + "\n");
    EstimationConfig changed = Parse("  profile: " + profile + "\n  huber_delta: 7\n");
    EXPECT_EQ(changed.huber_delta, 7.0) << profile;
    changed.huber_delta = base.huber_delta;
    ExpectSameOptions(changed, base);
  }
}

TEST(EstimationProfile, AnUnknownProfileIsNamedWithTheChoices) {
  const core::InputError e = Error("  profile: best\n");
  EXPECT_EQ(e.key_path(), "estimation.profile");
  EXPECT_EQ(e.location().line, 14);
  EXPECT_CONTAINS(e.what(), "expected " + core::ChoiceList(EstimationConfig::Fields().front().format));
  EXPECT_CONTAINS(e.what(), "paper");
}

// The recommended profile is the configuration docs/RESULTS.md reports as chosen
// (scripts/results.py source `profiles`): the same options as the paper's with the
// measured settings applied, read from docs/results/results.json.
TEST(EstimationProfile, RecommendedIsTheMeasuredChoice) {
  std::ifstream in(std::string(TOFU_SOURCE_DIR) + "/docs/results/results.json");
  ASSERT_TRUE(in.good());
  const nlohmann::json results = nlohmann::json::parse(in);
  const std::string settings =
      results.at("sources").at("profiles").at("values").at("profiles.recommended.settings");
  std::vector<std::string> chosen = {"profile=paper"};
  std::istringstream words(settings);
  for (std::string word; words >> word;) chosen.push_back(word);
  EstimationConfig measured = EstimationConfig::Defaults(EstimationProfile::kPaper);
  ApplyEstimationSettings(chosen, &measured);
  measured.profile = EstimationProfile::kRecommended;
  ExpectSameOptions(EstimationConfig::Defaults(EstimationProfile::kRecommended), measured);
}

// ---- rules between fields ----

// Each metric has its own scale: a metric named without a threshold gets its profile's
// threshold for that metric, never the other metric's.
TEST(EstimationRules, AMetricWithoutAThresholdGetsItsOwnProfileThreshold) {
  for (const EstimationProfile profile : replay::kEstimationProfiles) {
    const std::string name(replay::EstimationProfileName(profile));
    for (const auto& [word, metric] :
         {std::pair{"cm", ConsistencyMetric::kCm}, std::pair{"nis", ConsistencyMetric::kNis}}) {
      const EstimationConfig c = Parse("  profile: " + name + "\n  consensus: {metric: " + word + "}\n");
      EXPECT_EQ(c.consensus.metric, metric) << name << " " << word;
      EXPECT_EQ(c.consensus.threshold, EstimationConfig::DefaultThreshold(profile, metric))
          << name << " " << word;
    }
  }
}

TEST(EstimationRules, AThresholdOffItsMetricsScaleIsRefusedAtTheThreshold) {
  // 0.1 is cm's paper threshold in m/s; on nis's unitless scale it refuses healthy pairs.
  core::InputError e = Error("  consensus: {metric: nis, threshold: 0.1}\n");
  EXPECT_EQ(e.key_path(), "estimation.consensus.threshold");
  EXPECT_CONTAINS(e.what(), "for metric nis");
  EXPECT_CONTAINS(e.what(), "[1, 100]");
  // 3 is nis's; as a velocity distance it sees no fault.
  e = Error("  consensus: {metric: cm, threshold: 3}\n");
  EXPECT_EQ(e.key_path(), "estimation.consensus.threshold");
  EXPECT_CONTAINS(e.what(), "for metric cm");
  e = Error("  consensus: {threshold: 0.3, leave_threshold: 0.2}\n");
  EXPECT_EQ(e.key_path(), "estimation.consensus.leave_threshold");
  EXPECT_CONTAINS(e.what(), "at least threshold (0.3)");
  e = Error("  consensus: {bias_window_s: 0.2}\n");
  EXPECT_EQ(e.key_path(), "estimation.consensus.bias_window_s");
  EXPECT_CONTAINS(e.what(), "0 (off) or at least 0.5");
}

TEST(EstimationRules, AMetricTheConsensusDoesNotTakeIsNamedAtItsKey) {
  const core::InputError e = Error("  consensus: {metric: kl}\n");
  EXPECT_EQ(e.key_path(), "estimation.consensus.metric");
  EXPECT_EQ(e.location().line, 14);
  EXPECT_CONTAINS(e.what(), "cm or nis");
}

// The same misconfigured metric through the CLI: exit 2 naming the key, nothing flown.
TEST(EstimationRules, AMisconfiguredMetricIsExit2NamingTheKey) {
  const std::filesystem::path dir = test::PerTestDirectory("profile_");
  std::filesystem::create_directories(dir);
  test::WriteFile(dir / "bad.yaml", WithEstimation("  consensus: {metric: nis, threshold: 0.1}\n"));
  const test::CommandResult validate = test::RunTofu("validate bad.yaml", dir);
  EXPECT_EQ(validate.exit_code, 2) << validate.err;
  EXPECT_CONTAINS(validate.err, "bad.yaml:14:");
  EXPECT_CONTAINS(validate.err, "estimation.consensus.threshold");
  const test::CommandResult run = test::RunTofu("run bad.yaml --out flown", dir);
  EXPECT_EQ(run.exit_code, 2) << run.err;
  EXPECT_FALSE(std::filesystem::exists(dir / "flown"));
}

// ---- the resolved block ----

// Every option is written, with the profile: the block reproduces its configuration
// whatever profile a later reader defaults to, and the text lists every table key.
TEST(EstimationResolved, TheResolvedBlockWritesEveryKeyAndReadsBackTheSame) {
  for (const char* block : {"  profile: paper\n", "",
                            "  profile: paper\n  consensus: {metric: nis, leave_threshold: 4, "
                            "priority: [leica, vio]}\n  position_factors: offset\n"}) {
    const Scenario scenario = ParseScenario(WithEstimation(block), kLabel);
    const std::string resolved = ResolvedScenarioYaml(scenario);
    for (const auto& field : EstimationConfig::Fields()) {
      EXPECT_CONTAINS(resolved, "  " + std::string(field.format.key) + ": ");
    }
    for (const auto& field : replay::ConsensusConfig::Fields()) {
      if (field.format.key == "leave_threshold" && !scenario.estimation->consensus.leave_threshold) {
        continue;
      }
      EXPECT_CONTAINS(resolved, "    " + std::string(field.format.key) + ": ");
    }
    const Scenario reloaded = ParseScenario(resolved, "resolved.yaml");
    ExpectSameOptions(*reloaded.estimation, *scenario.estimation);
    EXPECT_EQ(reloaded.estimation->methods, scenario.estimation->methods);
    EXPECT_EQ(ResolvedScenarioYaml(reloaded), resolved);
  }
}

// ---- tofu estimate --set ----

TEST(EstimationSettings, ASettingChangesItsKeyAndAProfileSwitchesTheRest) {
  EstimationConfig c = Parse("  consensus: {threshold: 0.3, priority: [leica, vio]}\n  huber_delta: 3\n");
  ApplyEstimationSettings({"consensus.metric=nis", "position_factors=offset"}, &c);
  EXPECT_EQ(c.consensus.metric, ConsistencyMetric::kNis);
  EXPECT_EQ(c.consensus.threshold, EstimationConfig::DefaultThreshold(c.profile, ConsistencyMetric::kNis));
  EXPECT_EQ(c.position_factors, PositionFactors::kOffset);
  EXPECT_EQ(c.huber_delta, 3.0);
  EXPECT_CONTAINS(c.resolved_yaml, "metric: nis");

  // profile= applies first, whatever its place, and keeps methods and priority; what the
  // run set otherwise than its own profile (metric, its threshold, the position factors)
  // stays, what it left at the default (threshold 0.3 and Huber 3 are the recommended
  // profile's) takes the paper's.
  ApplyEstimationSettings({"huber_delta=2", "profile=paper"}, &c);
  EstimationConfig expected = Parse(fmt::format(
      "  profile: paper\n  consensus: {{metric: nis, threshold: {}, priority: [leica, vio]}}\n"
      "  position_factors: offset\n  huber_delta: 2\n",
      EstimationConfig::DefaultThreshold(EstimationProfile::kRecommended, ConsistencyMetric::kNis)));
  ExpectSameOptions(c, expected);
  EXPECT_EQ(c.methods, expected.methods);
}

// A scenario's own choices survive a switch of profile both ways; a key written at its
// profile's value is not told apart from one left out, and takes the new profile's.
TEST(EstimationSettings, AProfileSwitchKeepsTheRunsOwnChoices) {
  EstimationConfig c = Parse("  consensus: {leave_threshold: 0.6, fuse: consistent_set}\n");
  ApplyEstimationSettings({"profile=paper"}, &c);
  ExpectSameOptions(c, Parse("  profile: paper\n  consensus: {leave_threshold: 0.6, fuse: consistent_set}\n"));
  EstimationConfig paper = Parse("  profile: paper\n  huber_delta: 0\n  alignment_level_prior_deg: 0.35\n");
  ApplyEstimationSettings({"profile=recommended"}, &paper);
  ExpectSameOptions(paper, Parse("  alignment_level_prior_deg: 0.35\n"));
}

TEST(EstimationSettings, ABadSettingNamesWhatIsWrong) {
  const auto error = [](const std::vector<std::string>& settings) {
    EstimationConfig c = EstimationConfig::Defaults(EstimationProfile::kPaper);
    try {
      ApplyEstimationSettings(settings, &c);
    } catch (const core::InputError& e) {
      return std::string(e.what());
    }
    ADD_FAILURE() << "expected an InputError";
    return std::string();
  };
  EXPECT_CONTAINS(error({"huber=3"}), "no estimation key 'huber'");
  EXPECT_CONTAINS(error({"huber=3"}), "consensus.metric");
  EXPECT_CONTAINS(error({"huber_delta"}), "expected KEY=VALUE");
  EXPECT_CONTAINS(error({"consensus.metric=kl"}), "cm or nis");
  EXPECT_CONTAINS(error({"consensus.metric=nis", "consensus.threshold=0.2"}),
                  "consensus.threshold: expected a number in [1, 100] for metric nis");
  EXPECT_CONTAINS(error({"huber_delta=3\nprofile: paper"}), "--set");
}

// ---- the generated reference ----

TEST(EstimationReference, TheReferencePageListsEveryKeyWithEachProfilesDefault) {
  const std::string page = ScenarioReferenceMarkdown();
  for (const auto& field : EstimationConfig::Fields()) {
    EXPECT_CONTAINS(page, "| `" + std::string(field.format.key) + "` |");
    EXPECT_FALSE(field.format.doc.empty()) << field.format.key;
  }
  for (const auto& field : replay::ConsensusConfig::Fields()) {
    EXPECT_CONTAINS(page, "| `" + std::string(field.format.key) + "` |");
    EXPECT_FALSE(field.format.doc.empty()) << field.format.key;
  }
  std::string threshold_row = "| `threshold` | number > 0 (m/s for cm, unitless for nis) |";
  for (const EstimationProfile profile : replay::kEstimationProfiles) {
    threshold_row += " `" + core::FormatDouble(EstimationConfig::Defaults(profile).consensus.threshold) + "` |";
  }
  EXPECT_CONTAINS(page, threshold_row);
}

}  // namespace
}  // namespace tofu::harness
