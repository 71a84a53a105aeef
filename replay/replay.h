#pragma once
// Replay of recorded streams (a tofu run directory or a real robot's log, see
// recorded_log.h) through the multi-graph estimator, one method at a time, and the
// evaluation of what it produced: trajectory errors against the ground truth and the
// consistency of each sensor's velocity with the local estimate (seed paper Sec. 2.1).
// Used by `tofu estimate RUN_DIR` and by the run loop (harness/run.h).
//
// The public entry of the replay path, one header per concept:
//   replay_method.h      method names (ReplayMethod), the estimator's defaults for a log
//   method_runner.h      MethodRunner, Replay and what they produce (ReplayResult)
//   stream_comparison.h  a stream on its own: raw pose trajectory, local consistency
//   method_evaluation.h  ScoreMethod: a method's scores against ground truth and labels
//   method_writers.h     estimate_<method>.*, decisions.csv, consistency_<method>.csv
//   estimate_command.h   `tofu estimate` (RunEstimateCommand)

#include "replay/estimate_command.h"
#include "replay/method_evaluation.h"
#include "replay/method_runner.h"
#include "replay/method_writers.h"
#include "replay/replay_method.h"
#include "replay/stream_comparison.h"
