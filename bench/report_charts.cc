#include "bench/report_charts.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <vector>

#include "bench/bench_support.h"

namespace hscloc::bench {

using nlohmann::json;

std::string ScaleSvg(const json& scale) {
  struct Panel {
    std::string title;
    std::string key;
  };
  const std::vector<Panel> panels = {{"build-map time (s)", "build_map_s"},
                                     {"build-map peak memory (MB)", "build_map_peak_mb"},
                                     {"loaded map (MB)", "loaded_map_mb"},
                                     {"query p50 (ms)", "query_p50_ms"}};
  const double width = 260, height = 200, margin = 45;
  std::ostringstream svg;
  svg << fmt::format(
      "<svg xmlns='http://www.w3.org/2000/svg' width='{}' height='{}' font-family='sans-serif' "
      "font-size='11'>\n",
      width * panels.size(), height + 30);
  double min_points = 1e300, max_points = 0;
  for (const json& row : scale) {
    min_points = std::min(min_points, row["points"].get<double>());
    max_points = std::max(max_points, row["points"].get<double>());
  }
  const double log_min = std::log10(min_points) - 0.2, log_max = std::log10(max_points) + 0.2;
  for (size_t p = 0; p < panels.size(); ++p) {
    const double x0 = p * width + margin, x1 = (p + 1) * width - 10;
    const double y0 = height - 20, y1 = 25;
    double max_value = 0;
    for (const json& row : scale) max_value = std::max(max_value, row.value(panels[p].key, 0.0));
    max_value = max_value > 0 ? max_value * 1.15 : 1;
    svg << fmt::format("<text x='{}' y='15'>{}</text>\n", x0, panels[p].title);
    svg << fmt::format("<line x1='{0}' y1='{1}' x2='{2}' y2='{1}' stroke='black'/>\n", x0, y0, x1);
    svg << fmt::format("<line x1='{0}' y1='{1}' x2='{0}' y2='{2}' stroke='black'/>\n", x0, y0, y1);
    svg << fmt::format("<text x='{}' y='{}' text-anchor='end'>{:.3g}</text>\n", x0 - 3, y1 + 4,
                       max_value);
    svg << fmt::format("<text x='{}' y='{}' text-anchor='end'>0</text>\n", x0 - 3, y0);
    svg << fmt::format("<text x='{}' y='{}' text-anchor='middle'>3D points (log)</text>\n",
                       (x0 + x1) / 2, height + 12);
    std::string path;
    for (const json& row : scale) {
      if (!row.contains(panels[p].key)) continue;
      const double x = x0 + (std::log10(row["points"].get<double>()) - log_min) /
                                (log_max - log_min) * (x1 - x0);
      const double y = y0 - row[panels[p].key].get<double>() / max_value * (y0 - y1);
      path += fmt::format("{}{:.1f},{:.1f}", path.empty() ? "M" : " L", x, y);
      svg << fmt::format("<circle cx='{:.1f}' cy='{:.1f}' r='3' fill='#1f77b4'/>\n", x, y);
      svg << fmt::format("<text x='{:.1f}' y='{:.1f}' text-anchor='middle'>{}</text>\n", x, y - 6,
                         row["preset"].get<std::string>());
    }
    svg << fmt::format("<path d='{}' fill='none' stroke='#1f77b4'/>\n", path);
  }
  svg << "</svg>\n";
  return svg.str();
}

// Held-out point accuracy (masked decoding) against training wall time, one line per preset: how
// long a map of that size needs. Time on a log axis, since the presets train for minutes to hours.
std::string TrainingCurveSvg(const json& scale) {
  const double width = 560, height = 300, x0 = 55, x1 = width - 110, y0 = height - 40, y1 = 20;
  double min_seconds = 1e300, max_seconds = 1;
  for (const json& row : scale) {
    for (const json& check : row.value("held_out_curve", json::array())) {
      min_seconds = std::min(min_seconds, std::max(1.0, check["seconds"].get<double>()));
      max_seconds = std::max(max_seconds, check["seconds"].get<double>());
    }
  }
  if (min_seconds > max_seconds) return "";
  const double log_min = std::log10(min_seconds) - 0.1, log_max = std::log10(max_seconds) + 0.1;
  const auto x_of = [&](double seconds) {
    return x0 + (std::log10(std::max(1.0, seconds)) - log_min) / (log_max - log_min) * (x1 - x0);
  };
  const auto y_of = [&](double accuracy) { return y0 - accuracy * (y0 - y1); };
  std::ostringstream svg;
  svg << fmt::format(
      "<svg xmlns='http://www.w3.org/2000/svg' width='{}' height='{}' font-family='sans-serif' "
      "font-size='11'>\n",
      width, height);
  svg << fmt::format("<line x1='{0}' y1='{1}' x2='{2}' y2='{1}' stroke='black'/>\n", x0, y0, x1);
  svg << fmt::format("<line x1='{0}' y1='{1}' x2='{0}' y2='{2}' stroke='black'/>\n", x0, y0, y1);
  for (const double accuracy : {0.0, 0.5, 1.0}) {
    svg << fmt::format("<text x='{}' y='{:.1f}' text-anchor='end'>{:.0f}%</text>\n", x0 - 4,
                       y_of(accuracy) + 4, 100 * accuracy);
  }
  for (double decade = std::pow(10.0, std::ceil(log_min)); decade <= max_seconds * 1.26;
       decade *= 10) {
    svg << fmt::format("<text x='{:.1f}' y='{}' text-anchor='middle'>{:g} s</text>\n", x_of(decade),
                       y0 + 14, decade);
  }
  svg << fmt::format(
      "<text x='{}' y='{}' text-anchor='middle'>training wall time (log), 2 cores</text>\n",
      (x0 + x1) / 2, height - 6);
  svg << fmt::format(
      "<text x='{}' y='{}'>solid: held-out point</text><text x='{}' y='{}'>dashed: localized "
      "by day</text>\n",
      x1 + 10, y0 - 20, x1 + 10, y0 - 6);
  const char* colors[] = {"#1f77b4", "#ff7f0e", "#2ca02c", "#d62728"};
  size_t line = 0;
  for (const json& row : scale) {
    const json curve = row.value("held_out_curve", json::array());
    if (curve.empty()) continue;
    const char* color = colors[line % 4];
    std::string path;
    for (const json& check : curve) {
      const double x = x_of(check["seconds"].get<double>());
      const double y = y_of(check["point_accuracy"].get<double>());
      path += fmt::format("{}{:.1f},{:.1f}", path.empty() ? "M" : " L", x, y);
      svg << fmt::format("<circle cx='{:.1f}' cy='{:.1f}' r='2.5' fill='{}'/>\n", x, y, color);
    }
    svg << fmt::format("<path d='{}' fill='none' stroke='{}'/>\n", path, color);
    // Localization by day with each check's network, dashed.
    std::string localized;
    for (const json& point : row.value("localization_curve", json::array())) {
      if (!point.contains("day")) continue;
      const double x = x_of(point["seconds"].get<double>());
      const double y = y_of(point["day"].get<double>());
      localized += fmt::format("{}{:.1f},{:.1f}", localized.empty() ? "M" : " L", x, y);
    }
    if (!localized.empty()) {
      svg << fmt::format("<path d='{}' fill='none' stroke='{}' stroke-dasharray='5,3'/>\n",
                         localized, color);
    }
    svg << fmt::format("<text x='{}' y='{}' fill='{}'>{}</text>\n", x1 + 10, y1 + 14 * (line + 1),
                       color, row["preset"].get<std::string>());
    ++line;
  }
  svg << "</svg>\n";
  return svg.str();
}

}  // namespace hscloc::bench
