#include "report/error_curves.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <iterator>

#include "report/html.h"

namespace hscloc {
namespace {

constexpr const char* kCurveColors[] = {"#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e"};

// One panel of the SVG: the error on a log-scale x axis, the share of queries within it in y.
std::string ErrorPanel(const std::vector<ConditionAccuracy>& accuracies, bool rotation, double left,
                       double top, double width, double height) {
  // Errors below 1 cm or 0.01 deg are equally good; the range ends at 100 m or 180 deg.
  const double x_min = 0.01;
  const double x_max = rotation ? 180 : 100;
  const auto x_of = [&](double value) {
    const double clamped = std::clamp(value, x_min, x_max);
    return left + width * std::log10(clamped / x_min) / std::log10(x_max / x_min);
  };
  const auto y_of = [&](double fraction) { return top + height * (1 - fraction); };
  std::string svg;
  svg += fmt::format("<rect x='{}' y='{}' width='{}' height='{}' fill='none' stroke='#444'/>\n",
                     left, top, width, height);
  for (double tick = x_min; tick <= x_max * 1.0001; tick *= 10) {
    svg += fmt::format(
        "<line x1='{0:.1f}' y1='{1}' x2='{0:.1f}' y2='{2}' stroke='#ddd'/>"
        "<text x='{0:.1f}' y='{3}' font-size='11' text-anchor='middle'>{4:g}</text>\n",
        x_of(tick), top, top + height, top + height + 14, tick);
  }
  for (int percent = 0; percent <= 100; percent += 20) {
    svg += fmt::format(
        "<line x1='{0}' y1='{1:.1f}' x2='{2}' y2='{1:.1f}' stroke='#ddd'/>"
        "<text x='{3}' y='{4:.1f}' font-size='11' text-anchor='end'>{5}%</text>\n",
        left, y_of(percent / 100.0), left + width, left - 4, y_of(percent / 100.0) + 4, percent);
  }
  if (!accuracies.empty()) {
    for (const PoseThreshold& threshold : accuracies.front().thresholds) {
      const double x = x_of(rotation ? threshold.rotation_deg : threshold.position);
      svg += fmt::format(
          "<line x1='{0:.1f}' y1='{1}' x2='{0:.1f}' y2='{2}' stroke='#888' "
          "stroke-dasharray='4 3'/>\n",
          x, top, top + height);
    }
  }
  for (size_t c = 0; c < accuracies.size(); ++c) {
    std::vector<double> errors;
    for (const QueryPoseError& error : accuracies[c].errors) {
      errors.push_back(rotation ? error.rotation_deg : error.position);
    }
    std::sort(errors.begin(), errors.end());
    const double count = std::max<size_t>(errors.size(), 1);
    std::string points = fmt::format("{:.1f},{:.1f}", x_of(x_min), y_of(0));
    for (size_t i = 0; i < errors.size() && std::isfinite(errors[i]) && errors[i] <= x_max; ++i) {
      const double x = x_of(errors[i]);
      points +=
          fmt::format(" {:.1f},{:.1f} {:.1f},{:.1f}", x, y_of(i / count), x, y_of((i + 1) / count));
    }
    svg += fmt::format(
        "<polyline points='{} {:.1f},{:.1f}' fill='none' stroke='{}' stroke-width='2'/>\n", points,
        x_of(x_max),
        y_of(std::count_if(errors.begin(), errors.end(), [&](double e) { return e <= x_max; }) /
             count),
        kCurveColors[c % std::size(kCurveColors)]);
  }
  svg +=
      fmt::format("<text x='{}' y='{}' font-size='12' text-anchor='middle'>{}</text>\n",
                  left + width / 2, top + height + 32,
                  rotation ? "rotation error (deg, log scale)" : "position error (m, log scale)");
  return svg;
}

}  // namespace

std::string CumulativeErrorSvg(const std::vector<ConditionAccuracy>& accuracies,
                               const std::string& title) {
  constexpr double kPanelWidth = 380;
  constexpr double kPanelHeight = 260;
  std::string svg = fmt::format(
      "<svg xmlns='http://www.w3.org/2000/svg' width='{}' height='{}' font-family='sans-serif'>\n"
      "<rect width='100%' height='100%' fill='white'/>\n"
      "<text x='20' y='22' font-size='15'>{}</text>\n",
      2 * kPanelWidth + 140, kPanelHeight + 110, EscapeHtml(title));
  svg += ErrorPanel(accuracies, false, 60, 40, kPanelWidth, kPanelHeight);
  svg += ErrorPanel(accuracies, true, kPanelWidth + 120, 40, kPanelWidth, kPanelHeight);
  for (size_t c = 0; c < accuracies.size(); ++c) {
    svg += fmt::format(
        "<rect x='{}' y='{}' width='14' height='4' fill='{}'/>"
        "<text x='{}' y='{}' font-size='12'>{} ({} queries)</text>\n",
        60 + 200 * c, kPanelHeight + 88, kCurveColors[c % std::size(kCurveColors)], 80 + 200 * c,
        kPanelHeight + 94, EscapeHtml(accuracies[c].condition), accuracies[c].num_queries);
  }
  svg += "</svg>\n";
  return svg;
}

}  // namespace hscloc
