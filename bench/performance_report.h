// The Markdown report of hscloc-bench, written from its raw numbers (the JSON the run saves), with
// the scale plot (SVG) beside it: the same numbers always give the same report.
#pragma once

#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

namespace hscloc::bench {

// The report's Markdown; writes performance_scale.svg into report_path's directory.
std::string WriteReport(const nlohmann::json& results, const std::filesystem::path& report_path);

}  // namespace hscloc::bench
