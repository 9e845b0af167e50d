#include "report/demo_report.h"

#include "report/error_curves.h"
#include "report/html.h"
#include "report/localization_tables.h"

namespace hscloc {

std::string RenderDemoReport(const DemoReport& report) {
  HtmlPage page(report.title);
  if (!report.summary.empty()) page.AddParagraph(report.summary);

  page.AddHeading("Accuracy (server + hscloc-client batch)");
  page.AddTable(AccuracyTable(report.accuracy,
                              "Share of queries localized within each (position, rotation) "
                              "threshold; a query without an estimate fails every threshold"));
  page.AddFigureRow(
      {{CumulativeErrorSvg(report.accuracy, "Cumulative pose errors"),
        "Share of queries within a position (left) or rotation (right) error; dashed: the "
        "thresholds."},
       {TopViewSvg(report.top_view),
        "The map from above: each query's true camera centre joined to its estimate; crosses: "
        "failures."}});

  page.AddHeading("Ablations (in-process Localizer)");
  page.AddTable(AblationTable(report.ablations,
                              "Each variant changes one switch of the paper's configuration; "
                              "candidates posed and matches kept (after the visibility filter, "
                              "over the posed candidates) are means per query"));

  page.AddHeading("Latency per stage");
  page.AddTable(
      LatencyTable(report.ablations, report.latency_variant,
                   "Milliseconds per query, one core per query, " + report.latency_variant));

  if (!report.match_pictures.empty()) {
    page.AddHeading("Inlier matches");
    page.AddParagraph(
        "Query keypoints (left) and the 3D points they matched, projected into the retrieved "
        "database image (right); green: inliers of the pose, red: rejected matches.");
    std::vector<HtmlFigure> figures;
    for (const std::string& svg : report.match_pictures) figures.push_back({svg, ""});
    page.AddFigureRow(figures);
  }
  return page.Render();
}

}  // namespace hscloc
