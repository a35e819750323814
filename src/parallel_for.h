// tbb::parallel_for over a range, with its fork and join stated to ThreadSanitizer
// (thread_sanitizer.h): the tasks see what the caller wrote before the loop, and the caller sees
// what every task wrote once the loop returns. Nothing orders the tasks among themselves, so a
// race between two of them is still reported. Without -fsanitize=thread this is parallel_for.
#pragma once

#include "thread_sanitizer.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace penumbra::detail {

template <class Range, class Body>
void parallelFor(const Range& range, const Body& body) {
    const char forkKey = 0, joinKey = 0;
    tsanRelease(&forkKey);
    tbb::parallel_for(range, [&](const Range& part) {
        tsanAcquire(&forkKey);
        body(part);
        tsanRelease(&joinKey);
    });
    tsanAcquire(&joinKey);
}

}  // namespace penumbra::detail
