#pragma once
// Why the job manager refused a request, in its own words; the routes map the kind to
// an HTTP status (server/api/request_handler.cpp).
#include <stdexcept>
#include <string>

namespace tally {

class JobError : public std::runtime_error {
 public:
  enum class Kind { not_found, conflict, queue_full, unavailable, quota };
  JobError(Kind kind, const std::string& what) : std::runtime_error(what), kind_(kind) {}
  Kind kind() const noexcept { return kind_; }

 private:
  Kind kind_;
};

}  // namespace tally
