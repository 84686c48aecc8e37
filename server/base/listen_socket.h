// Listening sockets that refuse a port already taken.
#ifndef GEODESIC_SERVER_LISTEN_SOCKET_H_
#define GEODESIC_SERVER_LISTEN_SOCKET_H_

#include <sys/socket.h>

namespace geodesic::server {

// SO_REUSEADDR, so a restarted daemon binds over connections in TIME_WAIT,
// but not SO_REUSEPORT (cpp-httplib's and gRPC's default): with it a second
// daemon started on the same port would bind too, and the kernel would split
// clients between two daemons holding different meshes.
inline void ExclusiveListenSocket(int sock) {
  int yes = 1;
  setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof(yes));
}

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_LISTEN_SOCKET_H_
