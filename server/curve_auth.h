// CURVE for hscloc's sockets: a ZAP handler that admits the public keys of an allow-list per
// socket (its ZAP domain) and tags admin keys, and the socket options of a CURVE server and client.
// Keys are Z85 text (40 characters, from `hscloc keygen`).
#pragma once

#include <atomic>
#include <string>
#include <thread>
#include <vector>
#include <zmq.hpp>

namespace hscloc {

// The User-Id a connection of an admin key carries on every message (zmq_msg_gets "User-Id").
inline constexpr char kAdminUserId[] = "admin";

// Who may connect to the CURVE server sockets of one ZAP domain.
struct CurveDomain {
  std::string name;                       // the sockets' zmq::sockopt::zap_domain
  std::vector<std::string> allowed_keys;  // empty: any client that has the server's public key
  std::vector<std::string> admin_keys;    // admitted as well, and tagged kAdminUserId
};

// Throws std::invalid_argument naming `field` when `key` is not a Z85 CURVE key.
void CheckCurveKey(const std::string& key, const std::string& field);

// The ZAP handler of one context: binds inproc://zeromq.zap.01 (before any CURVE server socket
// of the context binds) and answers on a thread of its own until destroyed. Destroy it before
// closing the context.
class CurveAuthenticator {
 public:
  CurveAuthenticator(zmq::context_t& context, const std::vector<CurveDomain>& domains);
  ~CurveAuthenticator();
  CurveAuthenticator(const CurveAuthenticator&) = delete;
  CurveAuthenticator& operator=(const CurveAuthenticator&) = delete;

 private:
  std::atomic<bool> stopping_{false};
  std::thread thread_;
};

// Makes `socket` a CURVE server with `secret_key` whose clients the ZAP domain `domain` admits.
void MakeCurveServer(zmq::socket_t& socket, const std::string& secret_key,
                     const std::string& domain);
// Makes `socket` a CURVE client of the server with `server_public_key`, presenting the key pair
// of `secret_key` (its public half is derived from it).
void MakeCurveClient(zmq::socket_t& socket, const std::string& server_public_key,
                     const std::string& secret_key);

}  // namespace hscloc
