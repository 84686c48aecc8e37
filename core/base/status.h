// Small helpers for absl::Status plumbing. Debian 12's Abseil has no
// RETURN_IF_ERROR / ASSIGN_OR_RETURN, so we define them once, here.
#ifndef GEODESIC_CORE_BASE_STATUS_H_
#define GEODESIC_CORE_BASE_STATUS_H_

#include "absl/status/status.h"
#include "absl/status/statusor.h"

#define GEODESIC_CONCAT_INNER_(a, b) a##b
#define GEODESIC_CONCAT_(a, b) GEODESIC_CONCAT_INNER_(a, b)

#define RETURN_IF_ERROR(expr)                            \
  do {                                                   \
    ::absl::Status geodesic_status_ = (expr);            \
    if (!geodesic_status_.ok()) return geodesic_status_; \
  } while (0)

#define ASSIGN_OR_RETURN_IMPL_(tmp, lhs, expr) \
  auto tmp = (expr);                           \
  if (!tmp.ok()) return tmp.status();          \
  lhs = std::move(tmp).value()

#define ASSIGN_OR_RETURN(lhs, expr) \
  ASSIGN_OR_RETURN_IMPL_(GEODESIC_CONCAT_(geodesic_statusor_, __LINE__), lhs, expr)

#endif  // GEODESIC_CORE_BASE_STATUS_H_
