#pragma once
// Damage to a closed tally.db for the salvage tests (tests/server/store_test.cpp,
// tests/e2e/hardening_e2e.cpp): the b-tree header and cell pointers of the middle leaf
// page of the jobs table are overwritten, so the rows on that page are lost and the
// rest can still be read.
#include <SQLiteCpp/SQLiteCpp.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace tally::test {

struct DamagedPage {
  int64_t page_size = 0;
  size_t leaves = 0;     // leaf pages of the jobs table (the tests want at least 3)
  bool written = false;  // the page was overwritten
};

inline DamagedPage damage_middle_jobs_leaf(const std::filesystem::path& db) {
  DamagedPage d;
  std::vector<int64_t> leaves;
  {
    SQLite::Database sdb(db.string(), SQLite::OPEN_READONLY);
    d.page_size = sdb.execAndGet("PRAGMA page_size").getInt64();
    SQLite::Statement q(sdb, "SELECT pageno FROM dbstat WHERE name = 'jobs' AND pagetype = 'leaf' ORDER BY pageno");
    while (q.executeStep()) leaves.push_back(q.getColumn(0).getInt64());
  }
  d.leaves = leaves.size();
  if (leaves.empty()) return d;
  std::fstream f(db, std::ios::in | std::ios::out | std::ios::binary);
  f.seekp((leaves[leaves.size() / 2] - 1) * d.page_size);
  const std::string junk(64, '\xA5');
  f.write(junk.data(), static_cast<std::streamsize>(junk.size()));
  d.written = f.good();
  return d;
}

}  // namespace tally::test
