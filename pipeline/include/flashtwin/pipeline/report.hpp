#pragma once
// report.html of a run: one self-contained file (images embedded as data URIs) with the
// verdict, before/after renders, the scan with its flash labels, detected vs true paths, joint
// plots, forces and tracking over time, the residual flash map, the metrics table and the
// scenario's expectations. The PNGs are also left in DIR/report/.
#include <string>
#include <vector>

#include "flashtwin/core/transform.hpp"
#include "flashtwin/pipeline/execution.hpp"

namespace flashtwin::pipeline {

struct Scenario;
struct ScenarioScan;
struct RunResult;

struct ReportInputs {
  const Scenario& scenario;
  const ScenarioScan& scan;
  const RunResult& result;
  const std::vector<PlannedPath>& plans;
  const ExecutionSummary& execution;
};

/// Writes DIR/report.html (and DIR/report/*.png); returns the report's path.
/// @throws IoError when a file cannot be written; rendering errors are reported in the page.
std::string write_report(const std::string& dir, const ReportInputs& in);

/// RFC 4648 base64 of `bytes` (for data URIs).
std::string base64_encode(const std::string& bytes);

}  // namespace flashtwin::pipeline
