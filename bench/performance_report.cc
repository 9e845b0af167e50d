#include "bench/performance_report.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <vector>

#include "bench/bench_support.h"
#include "bench/report_charts.h"
#include "localization/stage_timings.h"

namespace hscloc::bench {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

std::string Percent(const json& fractions, size_t i) {
  return fractions.is_array() && i < fractions.size()
             ? fmt::format("{:.0f}%", 100 * fractions[i].get<double>())
             : "-";
}

std::string PeerRow(const std::string& name, const json& result, double map_bytes) {
  if (result.contains("skipped")) {
    std::string reason = result["skipped"].get<std::string>();
    reason = reason.substr(0, std::min(reason.find('\n'), size_t{120}));
    return fmt::format("| {} | - | - | - | - | - | {} |\n", name, reason);
  }
  const double ms = result.contains("ms_per_query")
                        ? result["ms_per_query"].get<double>()
                        : result["ms_per_query_one_thread"].get<double>();
  return fmt::format("| {} | {} | {} | {} | {:.3g} m | {:.0f} ms | {} |\n", name,
                     Percent(result["localized_fraction"], 0),
                     Percent(result["localized_fraction"], 1),
                     Percent(result["localized_fraction"], 2),
                     result["median_position"].get<double>(), ms, Megabytes(map_bytes));
}

// One query's errors by one method, "0.012 m, 0.05°", or why there are none.
std::string QueryErrorCell(const json& method, const std::string& query) {
  if (!method.contains("per_query")) return "-";
  for (const json& entry : method["per_query"]) {
    if (entry["name"] != query) continue;
    if (entry["position"].is_null()) return "no pose";
    return fmt::format("{:.3f} m, {:.2f}°", entry["position"].get<double>(),
                       entry["rotation_deg"].get<double>());
  }
  return "-";
}

// Each query's errors side by side, so that a query that slides does not hide behind a median.
std::string PerQueryTable(const json& peers) {
  if (!peers["hsc"].contains("per_query")) return "";
  std::string table =
      "| query | HSC | NN baseline | COLMAP image_registrator |\n| --- | --- | --- | --- |\n";
  for (const json& entry : peers["hsc"]["per_query"]) {
    const std::string query = entry["name"].get<std::string>();
    table +=
        fmt::format("| {} | {} | {} | {} |\n", query, QueryErrorCell(peers["hsc"], query),
                    QueryErrorCell(peers["nn"], query), QueryErrorCell(peers["colmap"], query));
  }
  return table + "\n";
}

// A matcher's median and worst position error over a seed's queries ("no pose" counts as worst).
std::string MedianAndWorst(const json& method) {
  double worst = 0;
  bool unposed = false;
  for (const json& entry : method.value("per_query", json::array())) {
    if (entry["position"].is_null()) {
      unposed = true;
    } else {
      worst = std::max(worst, entry["position"].get<double>());
    }
  }
  return fmt::format("{:.3f} m | {}", method["median_position"].get<double>(),
                     unposed ? "no pose" : fmt::format("{:.3f} m", worst));
}

// HSC and the nearest-neighbour baseline on every training seed of a real set, with the counts
// the method is judged by: every query within (0.25 m, 2°), HSC's median within 1.25x NN's.
std::string SeedsTable(const json& peers) {
  const json& seeds = peers["seeds"];
  std::string table = fmt::format(
      "Over {} training seeds:\n\n| seed | HSC (0.25 m, 2°) | HSC median | HSC worst | NN (0.25 m, "
      "2°) | NN median | NN worst | held-out accuracy (class means) | training | HSC map |\n| --- "
      "| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n",
      seeds.size());
  int all_within = 0;
  int median_within = 0;
  for (const json& seed : seeds) {
    const json& hsc = seed["hsc"];
    const json& nn = seed["nn"];
    std::string held_out = "-";
    if (seed.contains("held_out")) {
      held_out = fmt::format("{:.1f} % ({:.1f} %)", 100 * seed["held_out"]["network"].get<double>(),
                             100 * seed["held_out"]["nearest_class_mean"].get<double>());
    }
    all_within += hsc["localized_fraction"][0].get<double>() == 1.0;
    median_within +=
        hsc["median_position"].get<double>() <= 1.25 * nn["median_position"].get<double>();
    table +=
        fmt::format("| {} | {} | {} | {} | {} | {} | {:.0f} s | {} |\n", seed["seed"].get<int>(),
                    Percent(hsc["localized_fraction"], 0), MedianAndWorst(hsc),
                    Percent(nn["localized_fraction"], 0), MedianAndWorst(nn), held_out,
                    seed["train_s"].get<double>(), Megabytes(seed["hsc_bytes"].get<double>()));
  }
  return table + fmt::format(
                     "\nHSC placed every query within (0.25 m, 2°) on {} of {} seeds, and its "
                     "median position error was within 1.25x the baseline's on {} of {}.\n\n",
                     all_within, seeds.size(), median_within, seeds.size());
}

// "measured <date>" for a row measured apart from the run, with its CPU where that is not the
// header's; empty for a row of the run itself.
std::string Capitalized(std::string text) {
  if (!text.empty()) text[0] = static_cast<char>(std::toupper(static_cast<unsigned char>(text[0])));
  return text;
}

std::string MeasuredNote(const json& results, const json& row) {
  if (!row.contains("measured")) return "";
  std::string note = "measured " + row["measured"].get<std::string>();
  const std::string cpu = row.value("measured_cpu", std::string());
  if (!cpu.empty() && cpu != results["machine"].value("cpu", std::string())) note += " on " + cpu;
  return note;
}

// Where HSC's time goes on a preset's queries: per stage, then by class of query.
std::string StageTimingsTable(const json& peers) {
  if (!peers.contains("hsc") || !peers["hsc"].contains("timings")) return "";
  const json& timings = peers["hsc"]["timings"];
  std::string table = fmt::format(
      "Where HSC's time goes on {} (ms per query, each query on one core, two at a time; votes is "
      "part of retrieval, refine part of pose):\n\n| stage | mean | p50 | p95 | max |\n| --- | --- "
      "| --- | --- | --- |\n",
      peers["set"].get<std::string>());
  for (const StageField& field : kStageFields) {
    const json& stage = timings["stages"][std::string(field.name)];
    table += fmt::format("| {} | {:.1f} | {:.1f} | {:.1f} | {:.1f} |\n", field.name,
                         stage["mean"].get<double>(), stage["p50"].get<double>(),
                         stage["p95"].get<double>(), stage["max"].get<double>());
  }
  table +=
      "\n| queries | count | p50 | p95 | max | among the slowest 5 % |\n| --- | --- | --- | --- | "
      "--- | --- |\n";
  for (const json& entry : timings["classes"]) {
    table += fmt::format("| {} | {} | {:.0f} ms | {:.0f} ms | {:.0f} ms | {} |\n",
                         entry["class"].get<std::string>(), entry["queries"].get<int>(),
                         entry["p50"].get<double>(), entry["p95"].get<double>(),
                         entry["max"].get<double>(), entry["in_slowest_5_percent"].get<int>());
  }
  return table + "\n";
}

// "D0, lund and fountain-P11 on D1" from {"*": D0, "lund": D1, "fountain-P11": D1}; a plain
// string is one date for every set.
std::string MeasuredDates(const json& measured) {
  if (measured.is_string()) return measured.get<std::string>();
  std::map<std::string, std::vector<std::string>> sets_by_date;
  for (const auto& [set, date] : measured.items()) {
    if (set != "*") sets_by_date[date.get<std::string>()].push_back(set);
  }
  std::vector<std::string> parts;
  if (measured.contains("*")) parts.push_back(measured["*"].get<std::string>());
  for (const auto& [date, sets] : sets_by_date) {
    parts.push_back(fmt::format("{} on {}", fmt::join(sets, " and "), date));
  }
  return fmt::format("{}", fmt::join(parts, ", "));
}

std::string PeersTable(const json& peers) {
  // The network's held-out point accuracy beside the nearest-class-mean matcher's, where measured.
  std::string held_out;
  if (peers.contains("held_out")) {
    held_out = fmt::format("; held-out point accuracy {:.1f} %, nearest class mean {:.1f} %",
                           100 * peers["held_out"]["network"].get<double>(),
                           100 * peers["held_out"]["nearest_class_mean"].get<double>());
  }
  std::string table = fmt::format(
      "**{}** ({} queries; network trained {:.0f} s{})\n\n| method | (0.25 m, 2°) | (0.5 m, 5°) | "
      "(5 m, 10°) | median position | time per query | map on disk |\n| --- | --- | --- | --- | "
      "--- "
      "| --- | --- |\n",
      peers["set"].get<std::string>(), peers.value("queries", 0), peers.value("train_s", 0.0),
      held_out);
  if (peers.contains("skipped")) return table + "skipped: " + peers["skipped"].get<std::string>();
  const json& sizes = peers["sizes"];
  table += PeerRow("HSC (network + points + index)", peers["hsc"], sizes["hsc_bytes"]);
  table += PeerRow("NN baseline (descriptors + points + index)", peers["nn"], sizes["nn_bytes"]);
  table += PeerRow("COLMAP image_registrator (database.db + model)", peers["colmap"],
                   peers["colmap"].value("map_bytes", 0.0));
  if (peers.contains("auto")) {
    const json& choice = peers["auto"];
    table += fmt::format(
        "\n`--matcher auto` (the default) runs **{}** on this map: matching {} keypoints against "
        "{} "
        "images took the network {:.1f} ms and nearest neighbour {:.1f} ms on one core when it "
        "was trained.\n",
        choice["matcher"].get<std::string>(), choice["keypoints"].get<int>(),
        choice["images"].get<int>(), choice["network_ms"].get<double>(),
        choice["nearest_neighbor_ms"].get<double>());
  }
  table += "\n" + PerQueryTable(peers);
  if (peers.contains("seeds") && peers["seeds"].size() > 1) table += SeedsTable(peers);
  return table;
}

}  // namespace

namespace {

// The city's targets, each beside its measurement.
// The peaks the city's network was measured against: its own machine's where it was measured
// apart from the run.
const json& CityPeaks(const json& results) {
  const json& city = results["city"];
  return city.contains("machine") ? city["machine"] : results["machine"];
}

// The rate the network's floor was taken at: measured between its runs where the results have
// it, else the machine's peak of the same run.
double FloorPeakGflops(const json& network, const json& peaks) {
  return network.contains("floor_peak_gflops") ? network["floor_peak_gflops"].get<double>()
                                               : peaks["peak_gflops"].get<double>();
}

void WriteTargets(const json& results, std::ostringstream& md) {
  const json& peaks = CityPeaks(results);
  const json& city = results["city"];
  md << "## Targets (city preset, N = 2000 keypoints, K = 10 images, exhaustive)\n\n"
        "| target | measured | met |\n| --- | --- | --- |\n";
  if (city.contains("network")) {
    const json& network = city["network"];
    const json* grid_row = nullptr;
    for (const json& row : city["latency"]) {
      if (row["keypoints"] == 2000 && row["top_k"] == 10 && row["mode"] == "exhaustive") {
        grid_row = &row;
      }
    }
    const double times_floor = network["times_floor"];
    md << fmt::format(
        "| network within 1.5x of its FLOP floor | {:.2f}x ({:.1f} ms for {:.1f} "
        "GFLOP; floor {:.1f} ms at {:.0f} GFLOPS) | {} |\n",
        times_floor, network["predict_ms"].get<double>(), network["gflop"].get<double>(),
        network["floor_ms"].get<double>(), FloorPeakGflops(network, peaks),
        times_floor <= 1.5 ? "yes" : "no");
    if (grid_row != nullptr) {
      const double p50 = (*grid_row)["total"]["p50"];
      md << fmt::format("| end-to-end p50 under 300 ms | {:.0f} ms (p95 {:.0f} ms) | {} |\n", p50,
                        (*grid_row)["total"]["p95"].get<double>(), p50 < 300 ? "yes" : "no");
    }
    const json& server = city["server"];
    const double of_ideal = server["of_ideal"];
    md << fmt::format(
        "| server throughput at least 80% of workers / single-query latency | {:.0f}% ({:.2f} "
        "requests/s against {:.2f}) | {} |\n\n",
        100 * of_ideal, server["requests_per_s"].get<double>(),
        server["ideal_requests_per_s"].get<double>(), of_ideal >= 0.8 ? "yes" : "no");
  }
}

// The machine's GEMM peak, and the network against its floor.
void WriteMachineLimit(const json& results, std::ostringstream& md) {
  const json& city = results["city"];
  md << "## The machine's limit\n\n| fp32, all cores (products: 2048^3) | GFLOPS |\n| --- | --- "
        "|\n";
  const auto peak_rows = [&](const json& machine, const std::string& where) {
    md << fmt::format("| libtorch (OpenBLAS){} | {:.1f} |\n", where,
                      machine["libtorch_gflops"].get<double>());
    // Results before the packed product measured Eigen's instead, and no arithmetic peak.
    if (machine.contains("eigen_kernels_gflops")) {
      md << fmt::format("| hscloc kernels (Eigen, {}){} | {:.1f} |\n",
                        machine["kernel_instruction_sets"].get<std::string>(), where,
                        machine["eigen_kernels_gflops"].get<double>());
      return;
    }
    md << fmt::format(
        "| hscloc kernels (packed product, {}){} | {:.1f} |\n| the cores' arithmetic peak "
        "(fused multiply-adds on registers){} | {:.1f} |\n",
        machine["kernel_instruction_sets"].get<std::string>(), where,
        machine["kernels_gflops"].get<double>(), where, machine["fma_peak_gflops"].get<double>());
  };
  peak_rows(results["machine"], "");
  if (city.contains("machine")) {
    peak_rows(city["machine"], ", " + MeasuredNote(results, city) + " with the city");
  }
  md << "\n";
  if (city.contains("network")) {
    const json& network = city["network"];
    // Numbers measured before the kernels counted their work hold the shapes' count only.
    const std::string counted =
        network.contains("shape_gflop")
            ? fmt::format(
                  "of work done (the kernels count their matrix products: the modulation once "
                  "per run of rows sharing an image and label prefix, node outputs over a "
                  "parent's children only; its shapes count {:.2f})",
                  network["shape_gflop"].get<double>())
            : std::string("counted from its shapes (generator once per (image, keypoint) row)");
    md << fmt::format(
        "Network at N = 2000, K = 10 on the city map: {:.2f} GFLOP per query {}. hscloc's fused "
        "CPU kernels take {:.1f} ms ({:.0f} GFLOPS counted that way{}), {:.2f}x the floor of "
        "{:.1f} ms at {}. libtorch's operators on the same weights, the path "
        "before the kernels, take {:.0f} ms: the kernels are {:.1f}x faster. Per level, coarsest "
        "first: {:.1f} ms.\n\n",
        network["gflop"].get<double>(), counted, network["predict_ms"].get<double>(),
        network["achieved_gflops"].get<double>(),
        network.contains("shape_gflop")
            ? ""
            : "; the generator's deduplication of equal (image, label prefix) rows skips part of "
              "the counted work",
        network["times_floor"].get<double>(), network["floor_ms"].get<double>(),
        network.contains("floor_peak_gflops")
            ? fmt::format("{:.0f} GFLOPS, the best rate measured between its runs (the packed "
                          "product's median over {} windows of 0.3 s, or libtorch's)",
                          network["floor_peak_gflops"].get<double>(),
                          network["floor_rounds"].get<int>())
            : std::string("the best measured peak"),
        network["predict_libtorch_operators_ms"].get<double>(),
        network["predict_libtorch_operators_ms"].get<double>() /
            network["predict_ms"].get<double>(),
        fmt::join(network.value("level_ms", std::vector<double>{}), " / "));
  }
}

// The city's latency grid per stage, and the server under load.
void WriteCityLatency(const json& results, std::ostringstream& md) {
  const json& city = results["city"];
  double city_train_s = 0;
  for (const json& row : results["scale"]) {
    if (row["preset"] == "city") city_train_s = row["train_s"];
  }
  if (!city.contains("network")) return;
  md << "## End-to-end latency per stage (city, all cores for one query, ms, p50 / p95)\n\n";
  if (city.contains("measured")) {
    md << fmt::format("{} with the city's row (`--scale-only city`).\n\n",
                      Capitalized(MeasuredNote(results, city)));
  }
  md << "| keypoints | K | mode | retrieval | network | visibility | pose | total | localized "
        "|\n| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n";
  for (const json& row : city["latency"]) {
    const auto stage = [&](const char* key) {
      return fmt::format("{:.1f} / {:.1f}", row[key]["p50"].get<double>(),
                         row[key]["p95"].get<double>());
    };
    md << fmt::format("| {} | {} | {} | {} | {} | {} | {} | {} | {}/{} |\n",
                      row["keypoints"].get<int>(), row["top_k"].get<int>(),
                      row["mode"].get<std::string>(), stage("retrieval"), stage("network"),
                      stage("visibility"), stage("pose"), stage("total"),
                      row["localized"].get<int>(), row["queries"].get<int>());
  }
  const json& server = city["server"];
  md << fmt::format(
      "\nQueries are the city's day queries, cut to N keypoints or filled with clutter keypoints "
      "(uniform in the image, random descriptors). \"localized\": queries given a pose by this "
      "run's city network, trained {:.0f} s (its accuracy is in the peers below); the network's "
      "latency does not depend on training, RANSAC's does through its early stop.\n\n"
      "## Server over loopback\n\n{} workers "
      "(one thread each), N = 2000, K = 10. One client alone sees {:.0f} ms per request, so the "
      "pool's ideal is {:.2f} requests/s.\n\n| clients | requests/s | of ideal | p50 ms | p95 "
      "ms | p99 ms |\n| --- | --- | --- | --- | --- | --- |\n",
      city_train_s, server["workers"].get<int>(), server["single_query_ms"].get<double>(),
      server["ideal_requests_per_s"].get<double>());
  for (const json& row : server["load"]) {
    md << fmt::format("| {} | {:.2f} | {:.0f}% | {:.0f} | {:.0f} | {:.0f} |\n",
                      row["clients"].get<int>(), row["requests_per_s"].get<double>(),
                      100 * row["of_ideal"].get<double>(), row["p50_ms"].get<double>(),
                      row["p95_ms"].get<double>(), row["p99_ms"].get<double>());
  }
  md << "\n";
}

// The speed-ups with their before and after.
void WriteSpeedUps(const json& results, std::ostringstream& md) {
  const json& peaks = results["machine"];
  const json& city = results["city"];
  if (city.contains("network")) {
    const json& network = city["network"];
    md << fmt::format(
        "## Speed-ups, each measured\n\n| change | before | after | measured by |\n| --- | --- "
        "| --- | --- |\n| the network's CPU inference on fused kernels (docs/decisions.md) | "
        "{:.0f} ms (libtorch operators) | {:.1f} ms | this run: the same weights, N = 2000, K = "
        "10 |\n| OpenBLAS instead of ATLAS behind every `sgemm_` (docs/decisions.md) | 34 "
        "GFLOPS for libtorch's 2048^3 product; training 5.2k observations/s | {:.0f} GFLOPS; "
        "13.9k observations/s | `hscloc_network_benchmark` before and after the link change |\n\n"
        "Accuracy is kept: a test holds the fused kernels to libtorch's labels and confidences, "
        "and the peers below are measured on the fused path.\n\n",
        network["predict_libtorch_operators_ms"].get<double>(), network["predict_ms"].get<double>(),
        peaks["libtorch_gflops"].get<double>());
  }
}

// HSC, nearest neighbours and COLMAP on every real set and preset.
void WritePeers(const json& results, std::ostringstream& md) {
  md << "## Peers on the same data\n\nHSC and the nearest-neighbour baseline share the "
        "localizer's retrieval (10 candidates per round), the visibility filter and the pose "
        "stage; times are per query on one thread. "
        "COLMAP matches each query against every map image with its SIFT matcher, then registers "
        "it (`matches_importer` + `image_registrator`, wall time per query; the map images' "
        "matches among themselves, which its registration needs, are made beforehand and not "
        "timed). Map on disk: what "
        "each method must keep to localize. ";
  md << (results.value("quick", false)
             ? "Each real set's network trained for 20 s (--quick)."
             : "Each real set's network trained as `hscloc train` trains without a budget: the "
               "map's own, 5 % of the observations held out.");
  if (results.contains("real_sets_measured")) {
    md << fmt::format(" These rows were measured on {}, apart from the rest of the run.",
                      MeasuredDates(results["real_sets_measured"]));
  }
  md << "\n\n";
  for (const json& peers : results["real_sets"]) md << PeersTable(peers);
  for (const json& row : results["scale"]) {
    if (!row.contains("peers")) continue;
    for (const auto& [condition, peers] : row["peers"].items()) {
      json marked = peers;
      if (row.contains("measured")) {
        marked["set"] =
            fmt::format("{} ({})", peers["set"].get<std::string>(), MeasuredNote(results, row));
      }
      md << PeersTable(marked) << StageTimingsTable(marked);
    }
  }
}

// Build, training, size and latency per preset.
void WriteCostAgainstMapSize(const json& results, std::ostringstream& md) {
  md << "## Cost against map size\n\n![scale](performance_scale.svg)\n\n"
        "| preset | images | 3D points | observations | build-map | build-map peak memory | "
        "training | loaded map, with descriptors | bundle (HSC) | query p50 |\n"
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n";
  for (const json& row : results["scale"]) {
    md << fmt::format(
        "| {}{} | {} | {} | {} | {:.0f} s | {:.0f} MB | {:.0f} s | {:.0f} MB | {} | {:.0f} ms |\n",
        row["preset"].get<std::string>(),
        row.contains("measured") ? " (" + MeasuredNote(results, row) + ")" : "",
        row["images"].get<int64_t>(), row["points"].get<int64_t>(),
        row["observations"].get<int64_t>(), row["build_map_s"].get<double>(),
        row["build_map_peak_mb"].get<double>(), row["train_s"].get<double>(),
        row["loaded_map_mb"].get<double>(), Megabytes(row["sizes"]["hsc_bytes"].get<double>()),
        row["query_p50_ms"].get<double>());
  }
  md << "\nTraining ran for a fixed time budget per preset (more in a full run); query p50 uses "
        "the queries' own keypoints, K = 10, exhaustive, all cores.\n\n";
}

// Held-out accuracy and localization against training time, where measured.
void WriteTimeToAccuracy(const json& results, const fs::path& report_path, std::ostringstream& md) {
  const auto any_row_has = [&](const char* key) {
    for (const json& row : results["scale"]) {
      if (row.contains(key) && !row[key].empty()) return true;
    }
    return false;
  };
  if (any_row_has("held_out_curve")) {
    md << "## Time to accuracy\n\n![time to accuracy](performance_training.svg)\n\n"
          "| preset | first check at 90 % or more | last check | best check | localized day / "
          "night, first check | last check |\n"
          "| --- | --- | --- | --- | --- | --- |\n";
    for (const json& row : results["scale"]) {
      const json curve = row.value("held_out_curve", json::array());
      if (curve.empty()) continue;
      std::string first_90 = "never";
      const json* best = &curve.front();
      for (const json& check : curve) {
        if (first_90 == "never" && check["point_accuracy"].get<double>() >= 0.9) {
          first_90 = fmt::format("{:.0f} s (step {})", check["seconds"].get<double>(),
                                 check["iteration"].get<int64_t>());
        }
        if (check["point_accuracy"].get<double>() > (*best)["point_accuracy"].get<double>()) {
          best = &check;
        }
      }
      const auto describe = [](const json& check) {
        return fmt::format("{:.1f} % at {:.0f} s", 100 * check["point_accuracy"].get<double>(),
                           check["seconds"].get<double>());
      };
      const json localized = row.value("localization_curve", json::array());
      const auto describe_localized = [](const json& point) {
        return fmt::format("{:.0f} / {:.0f} % at {:.0f} s", 100 * point.value("day", 0.0),
                           100 * point.value("night", 0.0), point["seconds"].get<double>());
      };
      md << fmt::format("| {} | {} | {} | {} | {} | {} |\n", row["preset"].get<std::string>(),
                        first_90, describe(curve.back()), describe(*best),
                        localized.empty() ? "-" : describe_localized(localized.front()),
                        localized.empty() ? "-" : describe_localized(localized.back()));
    }
    md << "\nHeld-out point accuracy: the network's leaf for held-out observations of the map, "
          "decoded with the visibility mask of their image, as `hscloc train` checks it. "
          "Localized: queries within (0.25 m, 2 deg) with the network saved at that check "
          "(`hscloc train --snapshots`), a quarter of the accuracy table's queries.\n\n";
    std::ofstream(report_path.parent_path() / "performance_training.svg")
        << TrainingCurveSvg(results["scale"]);
  }
}

// What an operator provisions for: each number beside its bound (docs/deploy.md).
void WriteServing(const json& results, std::ostringstream& md) {
  const auto any_row_has = [&](const char* key) {
    for (const json& row : results["scale"]) {
      if (row.contains(key) && !row[key].empty()) return true;
    }
    return false;
  };
  if (any_row_has("serve_rss_mb")) {
    md << "## Serving a map\n\n"
          "| preset | build-map peak (aachen: <= 4096 MB) | "
          "`hscloc serve` resident (aachen: <= 1536 MB) | "
          "above the process with no map (small: <= 200 MB) | process with no map | "
          "load and verify (aachen: <= 5 s) |\n"
          "| --- | --- | --- | --- | --- | --- |\n";
    for (const json& row : results["scale"]) {
      if (!row.contains("serve_rss_mb")) continue;
      md << fmt::format(
          "| {} | {:.0f} MB | {:.0f} MB | {:.0f} MB | {:.0f} MB | {:.2f} s |\n",
          row["preset"].get<std::string>(), row["build_map_peak_mb"].get<double>(),
          row["serve_rss_mb"].get<double>(),
          row["serve_rss_mb"].get<double>() - row["process_baseline_rss_mb"].get<double>(),
          row["process_baseline_rss_mb"].get<double>(), row["serve_load_s"].get<double>());
    }
    md << "\nThe server is measured as an operator starts it (`hscloc serve --map`, the network "
          "matcher, one worker per core) once it listens, before any request; the process with "
          "no map is `hscloc --version`: the binary with its libraries (libtorch among them) "
          "loaded.";
    std::vector<std::string> remeasured;
    std::string how;
    for (const json& row : results["scale"]) {
      if (!row.contains("process_baseline_remeasured")) continue;
      remeasured.push_back(row["preset"].get<std::string>());
      how = row["process_baseline_remeasured"].get<std::string>();
    }
    if (!remeasured.empty()) {
      md << fmt::format(" The process with no map ({}) was measured apart from the run: {}.",
                        fmt::join(remeasured, ", "), how);
    }
    md << "\n\n";
  }
}

}  // namespace

std::string WriteReport(const json& results, const fs::path& report_path) {
  const json& peaks = results["machine"];
  std::ostringstream md;
  md << "# Performance\n\n";
  md << fmt::format(
      "Generated by `hscloc-bench{}` on {} ({} cores, {}), {}. Every number below comes from that "
      "one run unless marked otherwise; the raw numbers are in `{}`.\n\n",
      results["quick"].get<bool>() ? " --quick" : "", peaks["cpu"].get<std::string>(),
      peaks["threads"].get<int>(), peaks["kernel_instruction_sets"].get<std::string>(),
      results["date"].get<std::string>(), results["json_name"].get<std::string>());

  WriteTargets(results, md);
  WriteMachineLimit(results, md);
  WriteCityLatency(results, md);
  WriteSpeedUps(results, md);
  WritePeers(results, md);
  WriteCostAgainstMapSize(results, md);
  // Sections of numbers that older reports (their JSON) do not hold appear once measured.
  WriteTimeToAccuracy(results, report_path, md);
  WriteServing(results, md);
  md << "## Micro-benchmarks\n\nGoogle Benchmark executables in `build/bench/`, run by hand: "
        "`hscloc_network_benchmark` (Predict at the Aachen shape with per-level times, training "
        "throughput, libtorch's GEMM peak), `hscloc_retrieval_benchmark` (VLAD encoding, flat and "
        "IVF-PQ search), `hscloc_absolute_pose_benchmark` (RANSAC at 50, 20 and 10% inliers, with "
        "and without early stop, beside OpenCV's USAC) and `hscloc_map_load_benchmark` (bundle "
        "verification and loading).\n";
  std::ofstream(report_path.parent_path() / "performance_scale.svg") << ScaleSvg(results["scale"]);
  return md.str();
}

}  // namespace hscloc::bench
