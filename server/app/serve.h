// `geodesicd serve`.
#ifndef GEODESIC_SERVER_SERVE_H_
#define GEODESIC_SERVER_SERVE_H_

namespace geodesic::server {
int RunServe(int argc, char** argv);
}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_SERVE_H_
