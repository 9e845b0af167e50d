#include "bench/bench_support.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <iterator>
#include <regex>
#include <stdexcept>
#include <thread>

#include "util/timer.h"

namespace hscloc::bench {

namespace fs = std::filesystem;

namespace {

Timer& RunClock() {
  static Timer timer;
  return timer;
}

std::string FileTail(const fs::path& path, size_t bytes) {
  std::ifstream stream(path, std::ios::binary);
  const std::string text((std::istreambuf_iterator<char>(stream)), {});
  return text.size() > bytes ? text.substr(text.size() - bytes) : text;
}

}  // namespace

void Step(const std::string& message) {
  std::cerr << fmt::format("[{:6.1f} s] {}\n", RunClock().ElapsedSeconds(), message) << std::flush;
}

namespace {

// Starts `args` (args[0] found on PATH) with stdout and stderr into `log`; returns its pid.
pid_t StartChild(const std::vector<std::string>& args, const fs::path& log) {
  fs::create_directories(log.parent_path());
  const pid_t pid = fork();
  if (pid < 0) throw std::runtime_error("fork failed");
  if (pid == 0) {
    const int fd = open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd >= 0) {
      dup2(fd, STDOUT_FILENO);
      dup2(fd, STDERR_FILENO);
    }
    std::vector<char*> argv;
    for (const std::string& arg : args) argv.push_back(const_cast<char*>(arg.c_str()));
    argv.push_back(nullptr);
    execvp(argv[0], argv.data());
    std::fprintf(stderr, "cannot run %s\n", argv[0]);
    _exit(127);
  }
  return pid;
}

// VmRSS of a process, in MB; 0 when it cannot be read.
double ProcessResidentMegabytes(pid_t pid) {
  std::ifstream status(fmt::format("/proc/{}/status", pid));
  for (std::string line; std::getline(status, line);) {
    if (line.rfind("VmRSS:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;  // in kB
  }
  return 0;
}

std::string ReadFileText(const fs::path& path) {
  std::ifstream file(path);
  return std::string(std::istreambuf_iterator<char>(file), std::istreambuf_iterator<char>());
}

}  // namespace

// Runs `args` with stdout and stderr into `log`; throws with the log's tail when it fails.
ChildRun RunChild(const std::vector<std::string>& args, const fs::path& log) {
  Timer timer;
  const pid_t pid = StartChild(args, log);
  int status = 0;
  rusage usage{};
  wait4(pid, &status, 0, &usage);
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    throw std::runtime_error(fmt::format("`{} {}` failed (log {}):\n{}", args[0],
                                         args.size() > 1 ? args[1] : "", log.string(),
                                         FileTail(log, 1500)));
  }
  return {timer.ElapsedSeconds(), usage.ru_maxrss / 1024.0};
}

// A child's ru_maxrss counts the pages it shares with its parent between fork and exec: a child
// of this process (which holds maps of gigabytes) would report this process's memory. A small
// Python process forks the program instead, and reports its children's peak.
double ProgramPeakMegabytes(const std::vector<std::string>& args, const fs::path& log) {
  std::vector<std::string> python = {
      "python3", "-c",
      "import resource, subprocess, sys\n"
      "subprocess.run(sys.argv[1:], check=True, stdout=subprocess.DEVNULL)\n"
      "print('peak_kb', resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"};
  python.insert(python.end(), args.begin(), args.end());
  RunChild(python, log);
  const std::string text = ReadFileText(log);
  const size_t at = text.rfind("peak_kb ");
  if (at == std::string::npos) {
    throw std::runtime_error(fmt::format("no peak memory in {}:\n{}", log.string(), text));
  }
  return std::stod(text.substr(at + 8)) / 1024.0;
}

ServeRun MeasureServe(const std::string& hscloc, const fs::path& map_dir, const fs::path& log,
                      double timeout_s) {
  ServeRun run;
  run.baseline_rss_mb = ProgramPeakMegabytes({hscloc, "--version"}, log.string() + ".version");
  const pid_t pid = StartChild({hscloc, "serve", "--map", map_dir.string(), "--bind",
                                "tcp://127.0.0.1:0", "--admin-bind", "tcp://127.0.0.1:0"},
                               log);
  const Timer timer;
  std::string text;
  while (text.find("listening on") == std::string::npos) {
    int status = 0;
    if (waitpid(pid, &status, WNOHANG) == pid || timer.ElapsedSeconds() > timeout_s) {
      kill(pid, SIGKILL);
      waitpid(pid, &status, 0);
      throw std::runtime_error(fmt::format("hscloc serve did not start (log {}):\n{}", log.string(),
                                           FileTail(log, 1500)));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    text = ReadFileText(log);
  }
  run.rss_mb = ProcessResidentMegabytes(pid);
  // "loaded and verified map M from D in S s; <matcher>": the line goes on past the seconds, so
  // they are read where the line says them, not at its end.
  static const std::regex kLoaded(R"(loaded and verified map \S+ from .* in ([0-9.]+) s)");
  std::smatch loaded;
  if (std::regex_search(text, loaded, kLoaded)) run.load_seconds = std::stod(loaded[1].str());
  kill(pid, SIGTERM);
  int status = 0;
  waitpid(pid, &status, 0);
  return run;
}

bool CanRun(const std::string& program) {
  return std::system(fmt::format("command -v {} >/dev/null 2>&1", program).c_str()) == 0;
}

double ResidentMegabytes() {
  std::ifstream statm("/proc/self/statm");
  long pages = 0, resident = 0;
  statm >> pages >> resident;
  return resident * static_cast<double>(sysconf(_SC_PAGESIZE)) / (1 << 20);
}

uint64_t DirectoryBytes(const fs::path& dir, const std::vector<std::string>& exclude) {
  uint64_t bytes = 0;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    if (!entry.is_regular_file()) continue;
    const std::string name = entry.path().filename().string();
    if (std::find(exclude.begin(), exclude.end(), name) != exclude.end()) continue;
    bytes += entry.file_size();
  }
  return bytes;
}

std::string Megabytes(double bytes) { return fmt::format("{:.1f} MB", bytes / 1e6); }

}  // namespace hscloc::bench
