#include "server/metrics_http_server.h"

#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <spdlog/spdlog.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "util/check.h"

namespace hscloc {
namespace {

constexpr size_t kMaxRequestBytes = 8192;
constexpr int kConnectionTimeoutMs = 2000;

struct HostPort {
  std::string host;  // without an IPv6 address's brackets
  std::string port;
};

HostPort ParseBind(const std::string& bind, const std::string& option) {
  const size_t colon = bind.rfind(':');
  HostPort parsed;
  if (colon != std::string::npos) {
    parsed.host = bind.substr(0, colon);
    parsed.port = bind.substr(colon + 1);
  }
  if (parsed.host.size() >= 2 && parsed.host.front() == '[' && parsed.host.back() == ']') {
    parsed.host = parsed.host.substr(1, parsed.host.size() - 2);
  }
  if (parsed.host.empty() || parsed.port.empty() || parsed.port.size() > 5 ||
      parsed.port.find_first_not_of("0123456789") != std::string::npos ||
      std::stoi(parsed.port) > 65535) {
    ThrowInvalidArgument("{} '{}': expected host:port, e.g. 0.0.0.0:9464 (port 0: a free one)",
                         option, bind);
  }
  return parsed;
}

void SendAll(int connection, const std::string& data) {
  size_t sent = 0;
  while (sent < data.size()) {
    const ssize_t n = send(connection, data.data() + sent, data.size() - sent, MSG_NOSIGNAL);
    if (n <= 0) return;  // the scraper went away or timed out: nothing to tell anyone
    sent += static_cast<size_t>(n);
  }
}

std::string Response(const std::string& status, const std::string& content_type,
                     const std::string& body, bool with_body, const std::string& extra = "") {
  return "HTTP/1.1 " + status + "\r\nContent-Type: " + content_type +
         "\r\nContent-Length: " + std::to_string(body.size()) + "\r\n" + extra +
         "Connection: close\r\n\r\n" + (with_body ? body : "");
}

}  // namespace

MetricsHttpServer::MetricsHttpServer(const std::string& bind, const std::string& option,
                                     std::function<std::string()> exposition)
    : exposition_(std::move(exposition)) {
  const HostPort address = ParseBind(bind, option);
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE | AI_NUMERICSERV;
  addrinfo* found = nullptr;
  if (const int error = getaddrinfo(address.host.c_str(), address.port.c_str(), &hints, &found)) {
    ThrowInvalidArgument("cannot serve metrics on {} ({}): {}", bind, option, gai_strerror(error));
  }
  std::string failure = "no address";
  for (const addrinfo* candidate = found; candidate != nullptr && listener_ < 0;
       candidate = candidate->ai_next) {
    const int fd =
        socket(candidate->ai_family, candidate->ai_socktype | SOCK_CLOEXEC, candidate->ai_protocol);
    if (fd < 0) continue;
    const int reuse = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &reuse, sizeof(reuse));
    if (::bind(fd, candidate->ai_addr, candidate->ai_addrlen) == 0 && listen(fd, 16) == 0) {
      listener_ = fd;
    } else {
      failure = std::strerror(errno);
      close(fd);
    }
  }
  freeaddrinfo(found);
  if (listener_ < 0) {
    ThrowInvalidArgument("cannot serve metrics on {} ({}): {}", bind, option, failure);
  }
  sockaddr_storage bound{};
  socklen_t length = sizeof(bound);
  getsockname(listener_, reinterpret_cast<sockaddr*>(&bound), &length);
  const uint16_t port =
      ntohs(bound.ss_family == AF_INET6 ? reinterpret_cast<sockaddr_in6*>(&bound)->sin6_port
                                        : reinterpret_cast<sockaddr_in*>(&bound)->sin_port);
  const bool v6 = address.host.find(':') != std::string::npos;
  url_ = "http://" + (v6 ? "[" + address.host + "]" : address.host) + ":" + std::to_string(port) +
         "/metrics";
  if (pipe2(stop_pipe_, O_CLOEXEC) != 0) {
    close(listener_);
    ThrowInvalidArgument("cannot serve metrics on {}: no pipe ({})", bind, std::strerror(errno));
  }
  thread_ = std::thread([this] { Loop(); });
}

MetricsHttpServer::~MetricsHttpServer() {
  const char stop = 1;
  if (write(stop_pipe_[1], &stop, 1) != 1)
    spdlog::error("metrics endpoint: cannot stop its thread");
  thread_.join();
  close(listener_);
  close(stop_pipe_[0]);
  close(stop_pipe_[1]);
}

void MetricsHttpServer::Loop() {
  while (true) {
    pollfd items[2] = {{stop_pipe_[0], POLLIN, 0}, {listener_, POLLIN, 0}};
    if (poll(items, 2, -1) < 0) {
      if (errno == EINTR) continue;
      spdlog::error("metrics endpoint {}: poll failed ({})", url_, std::strerror(errno));
      return;
    }
    if (items[0].revents != 0) return;
    if (!(items[1].revents & POLLIN)) continue;
    const int connection = accept4(listener_, nullptr, nullptr, SOCK_CLOEXEC);
    if (connection < 0) continue;
    const timeval timeout{kConnectionTimeoutMs / 1000, (kConnectionTimeoutMs % 1000) * 1000};
    setsockopt(connection, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof(timeout));
    setsockopt(connection, SOL_SOCKET, SO_SNDTIMEO, &timeout, sizeof(timeout));
    Answer(connection);
    close(connection);
  }
}

void MetricsHttpServer::Answer(int connection) const {
  std::string request;
  char buffer[1024];
  while (request.find("\r\n\r\n") == std::string::npos &&
         request.find("\n\n") == std::string::npos && request.size() < kMaxRequestBytes) {
    const ssize_t n = recv(connection, buffer, sizeof(buffer), 0);
    if (n <= 0) break;
    request.append(buffer, static_cast<size_t>(n));
  }
  const std::string line = request.substr(0, request.find_first_of("\r\n"));
  const size_t method_end = line.find(' ');
  const size_t path_end = line.find(' ', method_end + 1);
  if (method_end == std::string::npos || path_end == std::string::npos ||
      line.compare(path_end + 1, 5, "HTTP/") != 0) {
    SendAll(connection, Response("400 Bad Request", "text/plain", "not an HTTP request\n", true));
    return;
  }
  const std::string method = line.substr(0, method_end);
  std::string path = line.substr(method_end + 1, path_end - method_end - 1);
  path = path.substr(0, path.find('?'));
  if (method != "GET" && method != "HEAD") {
    SendAll(connection, Response("405 Method Not Allowed", "text/plain", "GET /metrics only\n",
                                 true, "Allow: GET, HEAD\r\n"));
  } else if (path != "/metrics") {
    SendAll(connection, Response("404 Not Found", "text/plain", "the metrics are at /metrics\n",
                                 method == "GET"));
  } else {
    SendAll(connection, Response("200 OK", "text/plain; version=0.0.4; charset=utf-8",
                                 exposition_(), method == "GET"));
  }
}

}  // namespace hscloc
