#include "penumbra/mesh.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>
#include <tuple>
#include <unordered_map>

#include "penumbra/error.h"

namespace penumbra {

namespace {

using Edge = std::pair<uint32_t, uint32_t>;  // smaller index first

/// Indices of vertices with identical positions mapped to one representative, so that the
/// topology of a mesh written with per-corner vertices can be analysed.
std::vector<uint32_t> weldedIndices(const std::vector<Vec3>& vertices) {
    std::map<std::tuple<double, double, double>, uint32_t> first;
    std::vector<uint32_t> rep(vertices.size());
    for (uint32_t i = 0; i < vertices.size(); ++i) {
        const Vec3& p = vertices[i];
        rep[i] = first.emplace(std::make_tuple(p.x, p.y, p.z), i).first->second;
    }
    return rep;
}

/// Undirected edges used by exactly one (non-degenerate) triangle, in welded indices.
std::vector<Edge> boundaryEdges(const TriangleMesh& mesh, const std::vector<uint32_t>& rep) {
    std::map<Edge, int> uses;
    for (const auto& t : mesh.triangles) {
        for (int k = 0; k < 3; ++k) {
            uint32_t a = rep[t[k]], b = rep[t[(k + 1) % 3]];
            if (a == b) continue;
            if (a > b) std::swap(a, b);
            ++uses[{a, b}];
        }
    }
    std::vector<Edge> out;
    for (const auto& [edge, count] : uses) {
        if (count == 1) out.push_back(edge);
    }
    return out;
}

[[noreturn]] void fail(const std::string& file, size_t line, const std::string& message) {
    throw InputError(file, "line " + std::to_string(line), message);
}

double parseCoordinate(const std::string& token, const std::string& file, size_t line) {
    const char* begin = token.c_str();
    char* end = nullptr;
    errno = 0;
    const double x = std::strtod(begin, &end);
    if (end == begin || *end != '\0') {
        fail(file, line, "expected a number, got '" + token.substr(0, 40) + "'");
    }
    if (!std::isfinite(x) || errno == ERANGE) {
        fail(file, line, "coordinate '" + token.substr(0, 40) + "' is not a finite number");
    }
    return x;
}

/// A face corner "7", "7/2", "7/2/5" or "7//5" -> 0-based vertex index.
uint32_t parseCorner(const std::string& token, size_t vertexCount, const std::string& file,
                     size_t line) {
    const std::string index = token.substr(0, token.find('/'));
    const char* begin = index.c_str();
    char* end = nullptr;
    errno = 0;
    const long long i = std::strtoll(begin, &end, 10);
    if (end == begin || *end != '\0' || errno == ERANGE) {
        fail(file, line, "expected a vertex index, got '" + token.substr(0, 40) + "'");
    }
    // OBJ indices are 1-based; negative ones count back from the last vertex read so far.
    const long long n = static_cast<long long>(vertexCount);
    const long long zeroBased = i > 0 ? i - 1 : n + i;
    if (i == 0 || zeroBased < 0 || zeroBased >= n) {
        fail(file, line,
             "vertex index " + std::to_string(i) + " is out of range (" + std::to_string(n) +
                 " vertices read so far)");
    }
    return static_cast<uint32_t>(zeroBased);
}

}  // namespace

Box3 TriangleMesh::bounds() const {
    Box3 b;
    for (const Vec3& v : vertices) b.extend(v);
    return b;
}

double TriangleMesh::area() const {
    double sum = 0.0;
    for (const auto& t : triangles) {
        sum += 0.5 * glm::length(glm::cross(vertices[t[1]] - vertices[t[0]],
                                            vertices[t[2]] - vertices[t[0]]));
    }
    return sum;
}

size_t TriangleMesh::boundaryEdgeCount() const {
    return boundaryEdges(*this, weldedIndices(vertices)).size();
}

TriangleMesh readObj(const std::string& file) {
    std::ifstream in(file, std::ios::binary);
    if (!in) throw InputError(file, "", "cannot open the mesh file");
    TriangleMesh mesh;
    std::string text;
    size_t lineNo = 0;
    std::vector<uint32_t> corners;
    while (std::getline(in, text)) {
        ++lineNo;
        if (!text.empty() && text.back() == '\r') text.pop_back();
        std::istringstream line(text);
        std::string keyword;
        if (!(line >> keyword) || keyword[0] == '#') continue;
        if (keyword == "v") {
            std::string x, y, z;
            if (!(line >> x >> y >> z)) fail(file, lineNo, "a vertex needs 3 coordinates");
            mesh.vertices.emplace_back(parseCoordinate(x, file, lineNo),
                                       parseCoordinate(y, file, lineNo),
                                       parseCoordinate(z, file, lineNo));
        } else if (keyword == "f") {
            corners.clear();
            std::string token;
            while (line >> token) {
                corners.push_back(parseCorner(token, mesh.vertices.size(), file, lineNo));
            }
            if (corners.size() < 3) {
                fail(file, lineNo,
                     "a face needs at least 3 vertices, got " + std::to_string(corners.size()));
            }
            for (size_t k = 1; k + 1 < corners.size(); ++k) {
                mesh.triangles.push_back({corners[0], corners[k], corners[k + 1]});
            }
        }
        // Everything else (normals, texture coordinates, groups, materials) does not shape
        // the obstacle.
    }
    if (in.bad()) throw InputError(file, "", "cannot read the mesh file");
    if (mesh.vertices.size() > std::numeric_limits<uint32_t>::max()) {
        throw InputError(file, "", "too many vertices");
    }
    if (mesh.triangles.empty()) {
        throw InputError(file, "",
                         "the mesh has no faces (" + std::to_string(mesh.vertices.size()) +
                             " vertices, no 'f' lines)");
    }
    return mesh;
}

size_t capHoles(TriangleMesh& mesh) {
    const std::vector<uint32_t> rep = weldedIndices(mesh.vertices);
    const std::vector<Edge> edges = boundaryEdges(mesh, rep);
    if (edges.empty()) return 0;

    // Each boundary edge, directed as its triangle lists it: the cap must run the other way
    // along it, so that a consistently wound mesh stays consistently wound once capped.
    std::map<Edge, bool> forward;  // true: the triangle lists first -> second
    for (const auto& t : mesh.triangles) {
        for (int k = 0; k < 3; ++k) {
            const uint32_t a = rep[t[k]], b = rep[t[(k + 1) % 3]];
            const Edge e{std::min(a, b), std::max(a, b)};
            if (std::binary_search(edges.begin(), edges.end(), e)) forward[e] = a < b;
        }
    }
    // Walk the boundary graph along the cap's direction. Each vertex of a manifold boundary has
    // one edge leaving it that way; where several loops touch at a vertex, or the winding is
    // inconsistent, any unused edge continues the walk, which still yields closed loops.
    std::unordered_map<uint32_t, std::vector<size_t>> leaving, incident;
    for (size_t e = 0; e < edges.size(); ++e) {
        const auto [lo, hi] = edges[e];
        leaving[forward[edges[e]] ? hi : lo].push_back(e);  // the cap goes hi -> lo if forward
        incident[lo].push_back(e);
        incident[hi].push_back(e);
    }
    std::vector<bool> used(edges.size(), false);
    auto nextEdge = [&](uint32_t tip) {
        for (const auto* list : {&leaving[tip], &incident[tip]}) {
            for (size_t e : *list) {
                if (!used[e]) return e;
            }
        }
        return edges.size();
    };
    size_t holes = 0;
    for (size_t start = 0; start < edges.size(); ++start) {
        if (used[start]) continue;
        used[start] = true;
        const bool fwd = forward[edges[start]];
        std::vector<uint32_t> loop{fwd ? edges[start].second : edges[start].first,
                                   fwd ? edges[start].first : edges[start].second};
        for (;;) {
            const uint32_t tip = loop.back();
            const size_t next = nextEdge(tip);
            if (next == edges.size()) break;  // closed (or a dead end: cap the chain anyway)
            used[next] = true;
            const uint32_t other =
                edges[next].first == tip ? edges[next].second : edges[next].first;
            if (other == loop.front()) break;
            loop.push_back(other);
        }
        if (loop.size() < 3) continue;
        Vec3 centroid(0.0);
        for (uint32_t v : loop) centroid += mesh.vertices[v];
        centroid /= double(loop.size());
        const uint32_t c = static_cast<uint32_t>(mesh.vertices.size());
        mesh.vertices.push_back(centroid);
        for (size_t k = 0; k < loop.size(); ++k) {
            mesh.triangles.push_back({loop[k], loop[(k + 1) % loop.size()], c});
        }
        ++holes;
    }
    return holes;
}

}  // namespace penumbra
