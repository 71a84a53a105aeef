#include "report/html_search_page.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/file_io.h"
#include "replay/file_io.h"
#include "report/html_inputs.h"
#include "report/html_page.h"
#include "report/html_run_page.h"

namespace tofu::report::html {

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

// What the optimiser is told of a flight without a margin (campaign/search.cc).
constexpr double kClip = 10.0;

json ReadSearch(const fs::path& dir) {
  const fs::path path = dir / "search.json";
  const json search = json::parse(core::ReadWholeFile(path, "search record", 1ull << 30), nullptr, false);
  if (search.is_discarded() || !search.is_object() || search.value("format", "") != "tofu-search-1" ||
      !search.contains("evaluations") || !search.contains("failures")) {
    throw core::InputError({path.string()}, "", "not a tofu search record (expected search.json of format tofu-search-1)");
  }
  return search;
}

double MarginOf(const json& evaluation) {
  const json& m = evaluation.value("margin", json());
  return m.is_number() ? std::clamp(m.get<double>(), -kClip, kClip) : -kClip;
}

// Every search flight's margin (grey passing, red failing), the best so far, and the
// confirmed failures' first simulations, as an SVG.
std::string MarginChart(const json& search) {
  std::vector<double> margins;
  for (const json& e : search["evaluations"]) margins.push_back(MarginOf(e));
  if (margins.empty()) return "<p class=\"muted\">no search flights</p>";
  double lo = std::min(0.0, *std::min_element(margins.begin(), margins.end()));
  double hi = std::max(0.0, *std::max_element(margins.begin(), margins.end()));
  if (hi - lo < 1e-9) hi = lo + 1.0;
  constexpr double kWidth = 720, kHeight = 240, kLeft = 48, kRight = 708, kTop = 12, kBottom = 212;
  const double n = static_cast<double>(margins.size());
  const auto x = [&](double i) { return kLeft + (i - 0.5) / n * (kRight - kLeft); };
  const auto y = [&](double v) { return kBottom - (v - lo) / (hi - lo) * (kBottom - kTop); };
  std::string svg = fmt::format(
      "<svg class=\"margins\" width=\"{0}\" height=\"{1}\" viewBox=\"0 0 {0} {1}\" role=\"img\" "
      "aria-label=\"margins over the search\">"
      "<line x1=\"{2}\" y1=\"{4:.1f}\" x2=\"{3}\" y2=\"{4:.1f}\" stroke=\"#24292f\"/>"
      "<text x=\"{5}\" y=\"{6:.1f}\" font-size=\"10\" text-anchor=\"end\">{7:.3g}</text>"
      "<text x=\"{5}\" y=\"{8:.1f}\" font-size=\"10\" text-anchor=\"end\">{9:.3g}</text>"
      "<text x=\"{5}\" y=\"{4:.1f}\" font-size=\"10\" text-anchor=\"end\">0</text>",
      kWidth, kHeight, kLeft, kRight, y(0.0), kLeft - 4, kTop + 8, hi, kBottom, lo);
  for (const json& f : search["failures"]) {
    if (!f.value("confirmed", false) || !f.value("first_simulation", json()).is_number()) continue;
    const double at = x(f["first_simulation"].get<double>());
    svg += fmt::format("<line x1=\"{0:.1f}\" y1=\"{1}\" x2=\"{0:.1f}\" y2=\"{2}\" stroke=\"#cf222e\" "
                       "stroke-dasharray=\"3 3\"/><text x=\"{3:.1f}\" y=\"{4}\" font-size=\"10\" "
                       "fill=\"#cf222e\">{5}</text>",
                       at, kTop, kBottom, at + 3, kTop + 10, E(f.value("id", "")));
  }
  std::string best_path;
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < margins.size(); ++i) {
    const double m = margins[i];
    svg += fmt::format("<circle cx=\"{:.1f}\" cy=\"{:.1f}\" r=\"2.5\" fill=\"{}\"/>", x(i + 1.0), y(m),
                       m < 0.0 ? "#cf222e" : "#8c959f");
    const double before = best;
    best = std::min(best, m);
    best_path += i == 0 ? fmt::format("M{:.1f},{:.1f}", x(1.0), y(best))
                        : fmt::format(" L{:.1f},{:.1f} L{:.1f},{:.1f}", x(i + 1.0), y(before), x(i + 1.0), y(best));
  }
  svg += fmt::format("<path d=\"{}\" fill=\"none\" stroke=\"#0969da\" stroke-width=\"1.5\"/>", best_path);
  svg += fmt::format("<text x=\"{}\" y=\"{}\" font-size=\"10\" text-anchor=\"middle\">search simulation "
                     "(1-{}); blue: best margin so far; red: failing flights</text></svg>",
                     (kLeft + kRight) / 2, kHeight - 8, margins.size());
  return svg;
}

std::string MarginText(const json& margin) {
  const json& m = margin.value("margin", json());
  return m.is_number() ? E(Number(m.get<double>())) : std::string("none");
}

std::string ChangeText(const json& f) {
  std::string text;
  for (const json& line : f.value("shrunk_change", json::array())) {
    text += (text.empty() ? "" : "<br>") + E(line.is_string() ? line.get<std::string>() : "");
  }
  return text.empty() ? "-" : text;
}

// The shrunk flight's page under failures/<id>/; "" and `why` when it has none.
std::string WriteFailurePage(const fs::path& search_dir, const json& f, const fs::path& staging, std::string& why) {
  // A merged search's failures are in their shard's flights (run_dir, relative).
  const std::string flight = f.value("run_dir", "flights/" + f.value("shrunk_flight", ""));
  const fs::path run = search_dir / flight;
  if (flight.empty() || !fs::is_directory(run)) {
    why = fmt::format("its flight {} was not kept", flight);
    return "";
  }
  const fs::path dir = staging / "failures" / f.value("id", "");
  try {
    fs::create_directories(dir);
    WriteRunPage(ReadRunInputs(run), PageContext{dir, "../../index.html", ""});
  } catch (const core::InputError& e) {
    why = e.what();
    return "";
  }
  return Href(fs::path("failures") / f.value("id", "") / "index.html");
}

}  // namespace

bool IsSearchDirectory(const fs::path& dir) {
  std::error_code ec;
  if (!fs::is_regular_file(dir / "search.json", ec)) return false;
  try {
    ReadSearch(dir);
    return true;
  } catch (const std::exception&) {
    return false;
  }
}

void WriteSearchPages(const fs::path& search_dir, const fs::path& staging) {
  const json search = ReadSearch(search_dir);
  int confirmed = 0;
  for (const json& f : search["failures"]) confirmed += f.value("confirmed", false) ? 1 : 0;
  const json& sims = search.value("simulations", json::object());
  const json& first = search.value("simulations_to_first_confirmed", json());
  std::string objective;
  for (const json& o : search.value("objective", json::array())) {
    objective += (objective.empty() ? "" : ", ") + E(o.is_string() ? o.get<std::string>() : "");
  }
  std::string html = PageHead(fmt::format("tofu search {}", search.value("spec", "")));
  html += fmt::format(
      "<h1>tofu search {} {}</h1><p>Base <code>{}</code>; objective: the least margin of {}; optimiser {} "
      "(seed {}); {} search simulations of a budget of {}, {} to confirm, {} to shrink. {}</p>",
      E(search.value("spec", "")),
      Badge(confirmed == 0, "NO FAILURE FOUND", fmt::format("{} CONFIRMED FAILURE{}", confirmed, confirmed == 1 ? "" : "S")),
      E(search.value("base", "")), objective, E(search.value("optimizer", "")), search.value("optimizer_seed", 0),
      sims.value("search", 0), search.value("budget", 0), sims.value("confirm", 0), sims.value("shrink", 0),
      first.is_number() ? fmt::format("The first confirmed failure came at search simulation {}.", first.get<int>())
                        : std::string("No failure was confirmed."));
  html += Section("margins", "Margins over the search", MarginChart(search));

  std::string rows;
  int rank = 0;
  for (const json& f : search["failures"]) {
    const bool ok = f.value("confirmed", false);
    std::string why;
    const std::string page = ok ? WriteFailurePage(search_dir, f, staging, why) : std::string();
    const json& ci = f.value("failure_rate_ci95", json::array());
    const std::string rate = fmt::format(
        "{}/{} [{}, {}]", f.value("confirm_failures", 0), f.value("confirm_flights", 0),
        ci.size() == 2 && ci[0].is_number() ? fmt::format("{:.2f}", ci[0].get<double>()) : "?",
        ci.size() == 2 && ci[1].is_number() ? fmt::format("{:.2f}", ci[1].get<double>()) : "?");
    const std::string id = E(f.value("id", ""));
    const std::string link = !page.empty() ? fmt::format("<a href=\"{}\">{}</a>", page, id)
                             : ok          ? fmt::format("{} <span class=\"fail\">(no page: {})</span>", id, E(why))
                                           : id;
    const std::string cause = f.value("found_margin", json::object()).value("cause", "");
    rows += fmt::format(
        "<tr class=\"{}\"><td>{}</td><td>{}</td><td><code>{}</code></td><td>{}</td><td>{}</td><td>{}</td>"
        "<td>{}</td><td>{}</td><td>{}</td></tr>",
        ok ? "fail" : "muted", ++rank, link, E(f.value("expectation", "")), ok ? "yes" : "no", rate,
        MarginText(f.value("found_margin", json::object())),
        ok ? MarginText(f.value("shrunk_margin", json::object())) : "-", f.value("first_simulation", 0),
        ok ? ChangeText(f) : (cause.empty() ? "-" : "<pre>" + E(cause) + "</pre>"));
  }
  const std::string table =
      rows.empty() ? "<p>No flight failed.</p>"
                   : "<table><thead><tr><th>rank</th><th>failure</th><th>expectation</th><th>confirmed</th>"
                     "<th>failure rate [95 % CI]</th><th>margin found</th><th>margin shrunk</th>"
                     "<th>found at simulation</th><th>shrunk change from the base</th></tr></thead><tbody>" +
                         rows + "</tbody></table>";
  html += Section("failures", "Failures found", table);
  html += PageFoot(false);
  replay::WriteFileAtomically(staging / "index.html", html);
}

}  // namespace tofu::report::html
