#pragma once
// The style sheet and the plot script every report page inlines (private to report/):
// plain CSS with system fonts, and a dependency-free canvas plot, so a page needs no
// network and no library at view time.

namespace tofu::report {

/// The page's CSS: tables, pass green and fail red, the plot's frame and tooltip.
extern const char* const kReportCss;

/// The script behind every `.tofu-plot` element: reads the JSON of its
/// `script.plot-data` child ({series: [{name, color, dash, gap_s, t, y}], bands: [{t0, t1,
/// label}], y_label, unit, y_from_zero}) and draws it on its canvas; hover shows the time
/// and each series' value (`.plot-tip`), drag or wheel zooms in time, double-click resets,
/// the legend's buttons show or hide a series, "log scale" switches the y axis.
extern const char* const kPlotScript;

}  // namespace tofu::report
