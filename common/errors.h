// errors.h — the one exception type of progskin. Messages name the file (or
// packet, or argument) and what is wrong with it; tools print them on stderr
// and exit non-zero.
#pragma once
#include <stdexcept>
#include <string>

namespace progskin {

struct Error : std::runtime_error {
    using std::runtime_error::runtime_error;
};

}  // namespace progskin
