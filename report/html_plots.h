#pragma once
// Private to report/: the run page's interactive plots (canvas, drawn by the inline plot
// script of html_report_assets.h): errors over time with the scheduled faults shaded.

#include <string>
#include <vector>

#include "renders/run_data.h"
#include "report/html_inputs.h"

namespace tofu::report::html {

/// A shaded time span of a plot: a scheduled fault.
struct PlotBand {
  double t0_s = 0.0, t1_s = 0.0;
  std::string label;
};

/// Fault windows of labels.csv (source "fault"), in order of onset; one still active at the
/// end lasts to the end of the run.
std::vector<PlotBand> FaultBands(const renders::RunData& data);

/// The "Errors over time" section: each method's position error, the flights' tracking
/// error and distance to structure; "" when the run has none of them.
std::string PlotsSection(const RunInputs& in);

}  // namespace tofu::report::html
