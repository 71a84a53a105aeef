#pragma once
// The 2-D layer of a frame, drawn with mjr_* calls over MuJoCo's render of the scene: the
// text overlay (time, event, decision, faults, consistency values), the legend of ghost
// and sensor colours, and the consistency-matrix inset. Private to renders/: only
// scene_renderer.cc draws it; nothing outside renders/ includes this header.

#include <array>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <mujoco/mujoco.h>

#include "core/time.h"
#include "renders/run_data.h"

namespace tofu::renders {

using Rgba = std::array<float, 4>;

/// The marker colour of the k-th sensor of the run; the legend shows the same.
Rgba SensorColor(size_t sensor_index);

/// What the overlay needs to know of the frame it is drawn on.
struct OverlayFrame {
  int width_px = 640;
  int height_px = 480;
  int font_scale = mjFONTSCALE_100;  ///< the scale the context's fonts were made at
  bool heatmap = true;  ///< the inset is drawn: the text overlay leaves its values out
};

class Overlay {
 public:
  /// Chooses whose decisions and consistency values are shown. `ghosts` are the drawn
  /// estimates in GhostColor order; `consistency_metric` "" is the first in the files.
  /// `run`, the estimates and `context` must outlive the overlay. Throws core::InputError
  /// for a metric the run's consistency file lacks.
  Overlay(const RunData& run, std::vector<const MethodEstimate*> ghosts,
          const std::string& consistency_metric, const OverlayFrame& frame,
          const mjrContext* context);

  /// Text overlay, top left: time and camera, `caption`, the decision at `t_ns` (else the
  /// first ghost's fused sensors), active faults and conditions, consistency values.
  void DrawText(core::Time t_ns, const std::string& camera_name, const std::string& caption) const;
  /// Legend along the bottom: each ghost's and each sensor's colour.
  void DrawLegend() const;
  /// Consistency-matrix inset, top right (nothing without a matrix of two names or more).
  void DrawHeatmap(core::Time t_ns) const;

 private:
  const DecisionRow* DecisionAt(core::Time t_ns) const;
  std::map<std::pair<std::string, std::string>, double> ConsistencyAt(core::Time t_ns) const;
  int MaxOverlayLines() const;
  int TextHeight() const;
  bool LowIsGood() const;
  double Badness(double value) const;

  const RunData& run_;
  std::vector<const MethodEstimate*> ghosts_;
  OverlayFrame frame_;
  const mjrContext* context_;
  // Whose decisions and consistency values are shown.
  std::string decision_method_;
  const std::vector<ConsistencyRow>* consistency_ = nullptr;
  std::string consistency_metric_;
  double consistency_scale_ = 1.0;  // value of full "badness" for metrics where low is good
  std::vector<std::string> matrix_names_;
};

}  // namespace tofu::renders
