// `hscloc` as a child process for the end-to-end tests (HSCLOC_BINARY, defined by the test
// target): its output goes to a log, from which the lines it printed (endpoints, progress) are
// read, and it can be signalled.
#pragma once

#include <fmt/format.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "util/testing.h"

namespace hscloc::testing {

// The whole of a text file; empty when it cannot be read.
inline std::string ReadText(const std::filesystem::path& path) {
  std::ifstream file(path);
  return std::string(std::istreambuf_iterator<char>(file), std::istreambuf_iterator<char>());
}

// Runs `hscloc ARGUMENTS` to its end, its output in `log`; returns its exit status.
inline int RunHscloc(const std::string& arguments, const std::filesystem::path& log) {
  return RunCommand(fmt::format("{} {}", HSCLOC_BINARY, arguments), log.string());
}

class HsclocProcess {
 public:
  // Starts `hscloc ARGUMENTS...` (the subcommand first) with stdout and stderr in `log`.
  HsclocProcess(const std::vector<std::string>& arguments, std::filesystem::path log)
      : log_(std::move(log)) {
    const pid_t test_process = getpid();
    pid_ = fork();
    if (pid_ == 0) {
      // A test binary killed from outside (ctest's timeout kills it) must not leave servers
      // holding their ports for the next run. The signal follows the thread that forked, and the
      // tests start their processes from their main thread.
      prctl(PR_SET_PDEATHSIG, SIGTERM);
      if (getppid() != test_process) _exit(127);
      freopen(log_.c_str(), "w", stdout);
      freopen(log_.c_str(), "a", stderr);
      std::vector<char*> argv = {const_cast<char*>(HSCLOC_BINARY)};
      for (const std::string& argument : arguments)
        argv.push_back(const_cast<char*>(argument.c_str()));
      argv.push_back(nullptr);
      execv(HSCLOC_BINARY, argv.data());
      _exit(127);
    }
  }
  ~HsclocProcess() { Kill(); }
  HsclocProcess(const HsclocProcess&) = delete;
  HsclocProcess& operator=(const HsclocProcess&) = delete;

  std::string Log() const { return ReadText(log_); }
  // The rest of the first log line that starts with `prefix` ("listening on ", "admin on "),
  // waiting up to a minute for it; empty when it does not come or the process has ended without
  // it. Progress bars redraw with '\r': a line starts after either.
  std::string WaitForLine(const std::string& prefix) const {
    for (int wait = 0; wait < 600; ++wait) {
      const bool ended = Exited();  // before reading, so that its last words are in the log
      const std::string log = Log();
      for (size_t at = log.find(prefix); at != std::string::npos; at = log.find(prefix, at + 1)) {
        const size_t end = log.find('\n', at);
        if ((at == 0 || log[at - 1] == '\n' || log[at - 1] == '\r') && end != std::string::npos) {
          return log.substr(at + prefix.size(), end - at - prefix.size());
        }
      }
      if (ended) return "";
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    return "";
  }
  // Whether the process has ended (and been reaped: Kill and Terminate then leave it alone).
  bool Exited() const {
    if (pid_ <= 0) return true;
    int status = 0;
    if (waitpid(pid_, &status, WNOHANG) != pid_) return false;
    pid_ = -1;
    exit_status_ = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    return true;
  }
  void Kill() {
    if (pid_ <= 0) return;
    kill(pid_, SIGKILL);
    waitpid(pid_, nullptr, 0);
    pid_ = -1;
  }
  // Sends `signal` (SIGTERM by default), then returns the exit status (-1 when it did not exit
  // normally).
  int Terminate(int signal = SIGTERM) {
    // Never kill(-1, ...), which signals every process we may: an ended one keeps its status.
    if (pid_ <= 0) return exit_status_;
    kill(pid_, signal);
    int status = 0;
    waitpid(pid_, &status, 0);
    pid_ = -1;
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  }

 private:
  std::filesystem::path log_;
  mutable pid_t pid_ = -1;
  mutable int exit_status_ = -1;  // once reaped by Exited()
};

}  // namespace hscloc::testing
