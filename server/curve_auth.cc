#include "server/curve_auth.h"

#include <spdlog/spdlog.h>

#include <map>
#include <set>
#include <zmq_addon.hpp>

#include "util/check.h"

namespace hscloc {
namespace {

std::string DecodeKey(const std::string& key) {
  uint8_t binary[32];
  THROW_CHECK_MSG(zmq_z85_decode(binary, key.c_str()) != nullptr, "'{}' is no Z85 key", key);
  return std::string(reinterpret_cast<char*>(binary), 32);
}

// Binary public key -> User-Id, per domain.
struct AllowList {
  bool anyone = true;  // no client list: any key is admitted (the admin keys are still tagged)
  std::map<std::string, std::string> users;
};

std::map<std::string, AllowList> AllowLists(const std::vector<CurveDomain>& domains) {
  std::map<std::string, AllowList> lists;
  for (const CurveDomain& domain : domains) {
    AllowList& list = lists[domain.name];
    list.anyone = domain.allowed_keys.empty();
    for (const std::string& key : domain.allowed_keys) list.users[DecodeKey(key)] = "client";
    for (const std::string& key : domain.admin_keys) list.users[DecodeKey(key)] = kAdminUserId;
  }
  return lists;
}

// One ZAP request (RFC 27): version, request id, domain, address, identity, mechanism, key.
void Answer(zmq::socket_t& socket, const std::vector<zmq::message_t>& request,
            const std::map<std::string, AllowList>& lists) {
  if (request.size() < 7) return;
  const std::string domain = request[2].to_string();
  const std::string key = request[6].to_string();
  const auto list = lists.find(domain);
  std::string user = "client";
  bool admitted = false;
  if (list != lists.end()) {
    const auto found = list->second.users.find(key);
    admitted = list->second.anyone || found != list->second.users.end();
    if (found != list->second.users.end()) user = found->second;
  }
  if (!admitted) spdlog::warn("refused a CURVE key not allowed in domain '{}'", domain);
  const std::string reply[] = {"1.0",
                               request[1].to_string(),
                               admitted ? "200" : "400",
                               admitted ? "OK" : "key not allowed",
                               admitted ? user : "",
                               ""};
  for (size_t i = 0; i < 6; ++i) {
    socket.send(zmq::buffer(reply[i]),
                i + 1 < 6 ? zmq::send_flags::sndmore : zmq::send_flags::none);
  }
}

}  // namespace

void CheckCurveKey(const std::string& key, const std::string& field) {
  uint8_t binary[32];
  if (key.size() != 40 || zmq_z85_decode(binary, key.c_str()) == nullptr) {
    ThrowInvalidArgument("{}: '{}' is no Z85 CURVE key (40 characters)", field, key);
  }
}

CurveAuthenticator::CurveAuthenticator(zmq::context_t& context,
                                       const std::vector<CurveDomain>& domains) {
  zmq::socket_t socket(context, zmq::socket_type::rep);
  socket.set(zmq::sockopt::linger, 0);
  socket.bind("inproc://zeromq.zap.01");
  thread_ = std::thread([this, socket = std::move(socket), lists = AllowLists(domains)]() mutable {
    while (!stopping_) {
      zmq::pollitem_t item = {socket.handle(), 0, ZMQ_POLLIN, 0};
      try {
        zmq::poll(&item, 1, std::chrono::milliseconds(100));
        if (!(item.revents & ZMQ_POLLIN)) continue;
        std::vector<zmq::message_t> request;
        if (zmq::recv_multipart(socket, std::back_inserter(request)))
          Answer(socket, request, lists);
      } catch (const zmq::error_t&) {
        return;  // the context is closing
      }
    }
  });
}

CurveAuthenticator::~CurveAuthenticator() {
  stopping_ = true;
  if (thread_.joinable()) thread_.join();
}

void MakeCurveServer(zmq::socket_t& socket, const std::string& secret_key,
                     const std::string& domain) {
  socket.set(zmq::sockopt::zap_domain, domain);
  socket.set(zmq::sockopt::curve_server, 1);
  socket.set(zmq::sockopt::curve_secretkey, secret_key);
}

void MakeCurveClient(zmq::socket_t& socket, const std::string& server_public_key,
                     const std::string& secret_key) {
  char public_key[41];
  if (zmq_curve_public(public_key, secret_key.c_str()) != 0) {
    ThrowInvalidArgument("CURVE: cannot derive a public key from the secret key");
  }
  socket.set(zmq::sockopt::curve_serverkey, server_public_key);
  socket.set(zmq::sockopt::curve_publickey, std::string(public_key));
  socket.set(zmq::sockopt::curve_secretkey, secret_key);
}

}  // namespace hscloc
