// Helpers of hscloc-bench: progress lines and the command-line tools it runs as
// child processes, timed and with their peak memory.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace hscloc::bench {

// Prints "[seconds since start] message" to stderr.
void Step(const std::string& message);

struct ChildRun {
  double seconds = 0;
  // The child's ru_maxrss, which counts this process's pages shared between fork and exec: a
  // child's own peak only when it is above this process's resident memory (ProgramPeakMegabytes
  // measures any program).
  double peak_rss_mb = 0;
};

// Runs `args` (args[0] found on PATH) with stdout and stderr into `log`; throws
// std::runtime_error with the log's tail when it cannot start or exits non-zero.
ChildRun RunChild(const std::vector<std::string>& args, const std::filesystem::path& log);
// The peak resident memory of `args` alone, run from a small python3 process (its output into
// `log`); throws as RunChild does.
double ProgramPeakMegabytes(const std::vector<std::string>& args, const std::filesystem::path& log);
// Whether `program` is on PATH.
bool CanRun(const std::string& program);

// A server as an operator starts it: `hscloc serve` on loopback ports, measured once it listens.
struct ServeRun {
  double load_seconds = 0;     // load and verification of the map, as the server logs it
  double rss_mb = 0;           // resident memory once serving, before any request
  double baseline_rss_mb = 0;  // resident memory of `hscloc --version`: the process with no map
};
// Starts `hscloc serve --map map_dir` (its log in `log`), reads its memory once it listens, then
// stops it with SIGTERM. Throws with the log's tail when it exits or does not listen within
// `timeout_s`.
ServeRun MeasureServe(const std::string& hscloc, const std::filesystem::path& map_dir,
                      const std::filesystem::path& log, double timeout_s = 600);

// Resident memory of this process.
double ResidentMegabytes();
// Bytes of the regular files under `dir`, leaving out files named in `exclude`.
uint64_t DirectoryBytes(const std::filesystem::path& dir,
                        const std::vector<std::string>& exclude = {});
std::string Megabytes(double bytes);

}  // namespace hscloc::bench
