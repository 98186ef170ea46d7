// temp_dir.h — directories a test process makes under the system's temporary
// directory, removed with their contents when the process exits (a test
// binary runs once per test under ctest: hundreds of processes per run).
#pragma once
#include <unistd.h>

#include <filesystem>
#include <mutex>
#include <string>
#include <system_error>
#include <vector>

namespace progskin::testing {

// <tmp>/<prefix><pid><suffix>, emptied now (it may be left by a process of
// the same id) and removed at exit. The path; the caller creates it if it needs it.
inline std::filesystem::path process_temp_dir(const std::string& prefix, const std::string& suffix = "") {
    struct Registry {
        std::mutex m;
        std::vector<std::filesystem::path> paths;
        ~Registry() {
            std::error_code ec;
            for (const auto& p : paths) std::filesystem::remove_all(p, ec);
        }
    };
    static Registry r;
    const std::filesystem::path p = std::filesystem::temp_directory_path() / (prefix + std::to_string(::getpid()) + suffix);
    std::error_code ec;
    std::filesystem::remove_all(p, ec);
    std::lock_guard<std::mutex> lock(r.m);
    r.paths.push_back(p);
    return p;
}

}  // namespace progskin::testing
