#include "server/api/router.hpp"

#include <algorithm>

namespace tally {

namespace {

std::vector<std::string_view> split_path(std::string_view path) {
  std::vector<std::string_view> out;
  size_t i = 0;
  while (i < path.size()) {
    if (path[i] == '/') {
      ++i;
      continue;
    }
    const size_t j = path.find('/', i);
    out.push_back(path.substr(i, j == std::string_view::npos ? std::string_view::npos : j - i));
    if (j == std::string_view::npos) break;
    i = j;
  }
  return out;
}

bool is_param(std::string_view seg) { return seg.size() >= 2 && seg.front() == '{' && seg.back() == '}'; }

// Number of literal segments matched, or -1 if the pattern does not match.
int match_pattern(const Route& r, const std::vector<std::string_view>& segs, PathParams* params) {
  const auto& pat = r.segments;
  if (pat.size() != segs.size()) return -1;
  int literals = 0;
  for (size_t i = 0; i < pat.size(); ++i) {
    if (is_param(pat[i])) {
      if (segs[i].empty()) return -1;
      if (params) params->emplace(pat[i].substr(1, pat[i].size() - 2), url_decode(segs[i]));
    } else if (pat[i] == segs[i]) {
      ++literals;
    } else {
      return -1;
    }
  }
  return literals;
}

}  // namespace

void Router::add(std::string method, std::string pattern, RouteHandler handler, Lane lane) {
  Route r{std::move(method), std::move(pattern), std::move(handler), lane, {}};
  for (std::string_view seg : split_path(r.pattern)) r.segments.emplace_back(seg);
  routes_.push_back(std::move(r));
}

RouteMatch Router::match(std::string_view method, std::string_view path) const {
  const auto segs = split_path(path);
  RouteMatch m;
  int best = -1;
  for (const Route& r : routes_) {
    const int score = match_pattern(r, segs, nullptr);
    if (score < 0) continue;
    if (r.method == method) {
      if (score > best) {
        best = score;
        m.route = &r;
      }
    } else if (std::find(m.allow.begin(), m.allow.end(), r.method) == m.allow.end()) {
      m.allow.push_back(r.method);
    }
  }
  if (m.route) {
    match_pattern(*m.route, segs, &m.params);
    m.allow.clear();
  }
  return m;
}

}  // namespace tally
