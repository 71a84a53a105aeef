// The statistics of `tofu compare` (campaign/statistics.h) on inputs given as JSON lines,
// one answer per line: what tests/statistics_scipy_check.py holds to scipy.stats.
//   {"fn": "wilcoxon", "d": [...], "alternative": "greater"}        -> {"p": ...}
//   {"fn": "mannwhitney", "x": [...], "y": [...], "alternative": ...} -> {"p": ...}
//   {"fn": "mcnemar", "base_only": b, "new_only": c, "alternative": ...}
//   {"fn": "fisher", "base_yes": a, "base_n": n, "new_yes": b, "new_n": m, "alternative": ...}
//   {"fn": "bh", "p": [...]} / {"fn": "by", "p": [...]}               -> {"adjusted": [...]}
//   {"fn": "median", "x": [...]}                                      -> {"median": ...}

#include <iostream>
#include <string>

#include <nlohmann/json.hpp>

#include "campaign/statistics.h"

int main() {
  using tofu::campaign::Alternative;
  std::string line;
  while (std::getline(std::cin, line)) {
    const nlohmann::json q = nlohmann::json::parse(line);
    const std::string fn = q.at("fn");
    const Alternative alternative = q.value("alternative", "greater") == "greater"
                                        ? Alternative::kGreater
                                        : Alternative::kLess;
    nlohmann::json a;
    if (fn == "wilcoxon") {
      a["p"] = tofu::campaign::WilcoxonSignedRankP(q.at("d").get<std::vector<double>>(), alternative);
    } else if (fn == "mannwhitney") {
      a["p"] = tofu::campaign::MannWhitneyP(q.at("x").get<std::vector<double>>(),
                                            q.at("y").get<std::vector<double>>(), alternative);
    } else if (fn == "mcnemar") {
      a["p"] = tofu::campaign::McNemarExactP(q.at("base_only"), q.at("new_only"), alternative);
    } else if (fn == "fisher") {
      a["p"] = tofu::campaign::FisherExactP(q.at("base_yes"), q.at("base_n"), q.at("new_yes"),
                                            q.at("new_n"), alternative);
    } else if (fn == "bh") {
      a["adjusted"] = tofu::campaign::BenjaminiHochberg(q.at("p").get<std::vector<double>>());
    } else if (fn == "by") {
      a["adjusted"] = tofu::campaign::BenjaminiYekutieli(q.at("p").get<std::vector<double>>());
    } else if (fn == "median") {
      a["median"] = tofu::campaign::Median(q.at("x").get<std::vector<double>>());
    } else {
      std::cerr << "statistics_probe: unknown fn " << fn << "\n";
      return 2;
    }
    std::cout << a.dump() << "\n";
  }
  return 0;
}
