// The service's options, checked before anything starts, and the ids and keys a deployment
// names: the map id a service serves a bundle under, and CURVE key pairs.
#include <fmt/format.h>
#include <zmq.h>

#include <algorithm>

#include "server/curve_auth.h"
#include "server/localization_service.h"
#include "util/check.h"
#include "util/sha256.h"

namespace hscloc {

void ServiceOptions::Check() const {
  THROW_CHECK_MSG(!bind.empty() || !connect.empty(), "ServiceOptions.bind is empty");
  THROW_CHECK_MSG(connect.size() <= 255, "ServiceOptions.connect: {} brokers, at most 255",
                  connect.size());
  for (size_t i = 0; i < connect.size(); ++i) {
    THROW_CHECK_MSG(!connect[i].empty(), "ServiceOptions.connect (--connect): an empty endpoint");
    THROW_CHECK_MSG(
        std::find(connect.begin(), connect.begin() + i, connect[i]) == connect.begin() + i,
        "ServiceOptions.connect (--connect): {} is given twice", connect[i]);
  }
  THROW_CHECK_MSG(max_queue >= 1, "ServiceOptions.max_queue = {}", max_queue);
  THROW_CHECK_MSG(max_message_bytes >= 1024, "ServiceOptions.max_message_bytes = {}",
                  max_message_bytes);
  THROW_CHECK_MSG(heartbeat_interval.count() > 0 && heartbeat_liveness >= 2,
                  "ServiceOptions: heartbeat_interval {} ms, heartbeat_liveness {}",
                  heartbeat_interval.count(), heartbeat_liveness);
  if (!curve_secret_key.empty()) {
    CheckCurveKey(curve_secret_key, "ServiceOptions.curve_secret_key (--curve-secret-key)");
  }
  for (const std::string& key : curve_allowed_client_keys) {
    CheckCurveKey(key, "ServiceOptions.curve_allowed_client_keys (--curve-allowed-keys)");
  }
  for (const std::string& key : curve_admin_keys) {
    CheckCurveKey(key, "ServiceOptions.curve_admin_keys (--curve-admin-keys)");
  }
  if (!connect.empty()) {
    // A worker admits no clients: the broker does, and a worker cannot see the clients' keys.
    THROW_CHECK_MSG(curve_allowed_client_keys.empty() && curve_admin_keys.empty(),
                    "ServiceOptions.curve_allowed_client_keys and curve_admin_keys "
                    "(--curve-allowed-keys, --curve-admin-keys): a worker (--connect) admits no "
                    "clients; give them to the broker");
    THROW_CHECK_MSG(curve_secret_key.empty() == curve_server_key.empty(),
                    "ServiceOptions.curve_secret_key and curve_server_key: a worker (--connect) "
                    "authenticates to its broker with both its secret key (--curve-secret-key) "
                    "and the public key of the broker's backend (--curve-server-key)");
  } else {
    THROW_CHECK_MSG(curve_server_key.empty(),
                    "ServiceOptions.curve_server_key (--curve-server-key): only a worker "
                    "(--connect) connects to a CURVE server");
    THROW_CHECK_MSG(
        !curve_secret_key.empty() ||
            (curve_allowed_client_keys.empty() && curve_admin_keys.empty()),
        "ServiceOptions.curve_allowed_client_keys and curve_admin_keys (--curve-allowed-keys, "
        "--curve-admin-keys) need the server's CURVE key (--curve-secret-key)");
  }
  if (!curve_server_key.empty()) {
    CheckCurveKey(curve_server_key, "ServiceOptions.curve_server_key (--curve-server-key)");
  }
  localizer.Check();
}

std::string MapIdOf(const std::filesystem::path& map_dir, const std::string& manifest_sha256) {
  const std::filesystem::path canonical = std::filesystem::weakly_canonical(map_dir);
  return fmt::format("{}@{}", canonical.filename().string(), manifest_sha256.substr(0, 16));
}

std::string MapIdOf(const std::filesystem::path& map_dir) {
  return MapIdOf(map_dir, Sha256HexOfFile(map_dir / "manifest.json"));
}

CurveKeyPair GenerateCurveKeyPair() {
  char public_key[41];
  char secret_key[41];
  if (zmq_curve_keypair(public_key, secret_key) != 0) {
    ThrowInvalidArgument("CURVE key generation failed: libzmq lacks CURVE support");
  }
  return {public_key, secret_key};
}

}  // namespace hscloc
