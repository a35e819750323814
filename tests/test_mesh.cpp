// Tests of mesh.h: OBJ reading (forms of face corners, polygons, relative indices), the refusals
// with their line numbers, and hole capping.
#include <unistd.h>

#include <atomic>
#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>
#include <string>

#include "support/temp_file.h"
#include "penumbra/error.h"
#include "penumbra/mesh.h"

using namespace penumbra;
namespace fs = std::filesystem;

namespace {

/// Writes `text` to a fresh .obj file under the temp dir and removes it at scope exit.
struct TempObj : test::TempFile {
    explicit TempObj(const std::string& text) : test::TempFile("mesh", ".obj", text) {}
};

// A unit cube from 0 to 1 with quad faces, corners listed in the usual binary order.
const std::string kCubeVertices =
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 0 1\nv 1 0 1\nv 0 1 1\nv 1 1 1\n";
const std::string kCubeFaces =
    "f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n";

InputError objRefusal(const std::string& text) {
    TempObj obj(text);
    try {
        readObj(obj.path());
    } catch (const InputError& e) {
        CHECK(e.file() == obj.path());
        return e;
    }
    FAIL("accepted: " << text);
    throw std::logic_error("unreachable");
}

}  // namespace

TEST_CASE("OBJ faces in every corner form, polygons split into fans", "[mesh][scenes]") {
    TempObj obj("# a cube\no cube\n" + kCubeVertices +
                "vn 0 0 1\nvt 0 0\ng sides\ns off\nusemtl grey\n"
                // v, v/vt, v/vt/vn and v//vn corners, and relative (negative) indices.
                "f 1/1 3/1 4/1 2/1\nf 5//1 6//1 8//1 7//1\nf 1/1/1 2/1/1 6/1/1 5/1/1\n"
                "f -6 -2 -1 -5\nf 1 5 7 3\nf 2 4 8 6\r\n");
    const TriangleMesh mesh = readObj(obj.path());
    CHECK(mesh.vertices.size() == 8);
    REQUIRE(mesh.triangles.size() == 12);  // six quads, two triangles each
    // The fourth face, "-6 -2 -1 -5" after 8 vertices, is 3 7 8 4.
    CHECK(mesh.triangles[6] == std::array<uint32_t, 3>{2, 6, 7});
    CHECK(mesh.triangles[7] == std::array<uint32_t, 3>{2, 7, 3});
    CHECK(mesh.area() == Approx(6.0));
    CHECK(mesh.boundaryEdgeCount() == 0);
    const Box3 b = mesh.bounds();
    CHECK(b.lo == Vec3(0.0));
    CHECK(b.hi == Vec3(1.0));
}

TEST_CASE("malformed OBJ files are refused with the line", "[mesh][scenes]") {
    auto refused = [](const std::string& text, const std::string& where,
                      const std::string& fragment) {
        INFO(text);
        const InputError e = objRefusal(text);
        INFO(e.what());
        CHECK(e.where() == where);
        CHECK(std::string(e.what()).find(fragment) != std::string::npos);
    };
    refused("v 0 0 0\nv 1 0 0\nv 0 x 0\n", "line 3", "expected a number, got 'x'");
    refused("v 0 0\n", "line 1", "a vertex needs 3 coordinates");
    refused("v 0 0 1e999\n", "line 1", "not a finite number");
    refused("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "line 4", "at least 3 vertices, got 2");
    refused("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "line 4",
            "vertex index 4 is out of range (3 vertices read so far)");
    refused("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", "line 4", "vertex index 0 is out of range");
    refused("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 2 3\n", "line 4", "vertex index -4 is out of range");
    // A face may only use vertices defined before it.
    refused("v 0 0 0\nv 1 0 0\nf 1 2 3\nv 0 1 0\n", "line 3", "out of range (2 vertices");
    refused("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 a\n", "line 4", "expected a vertex index");
    refused("v 0 0 0\nv 1 0 0\nv 0 1 0\n", "", "no faces (3 vertices");
    refused("", "", "no faces");

    try {
        readObj((fs::temp_directory_path() / "penumbra_no_such_mesh.obj").string());
        FAIL("read a missing file");
    } catch (const InputError& e) {
        CHECK(e.message() == "cannot open the mesh file");
    }
}

TEST_CASE("capHoles closes each boundary loop with a fan", "[mesh][scenes]") {
    // The cube without its top (z = 1) face: one square hole.
    TempObj open(kCubeVertices + "f 1 3 4 2\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n");
    TriangleMesh mesh = readObj(open.path());
    CHECK(mesh.boundaryEdgeCount() == 4);
    CHECK(capHoles(mesh) == 1);
    CHECK(mesh.boundaryEdgeCount() == 0);
    // One centroid vertex at the middle of the missing face, four triangles around it.
    REQUIRE(mesh.vertices.size() == 9);
    CHECK(mesh.vertices.back() == Vec3(0.5, 0.5, 1.0));
    CHECK(mesh.triangles.size() == 10 + 4);
    CHECK(mesh.area() == Approx(6.0));
    // The cap is wound like the faces around it (outward here), so the divergence theorem gives
    // the cube's volume; a cap wound the other way would give 1/3.
    double volume = 0.0;
    for (const auto& t : mesh.triangles) {
        volume += glm::dot(mesh.vertices[t[0]],
                           glm::cross(mesh.vertices[t[1]], mesh.vertices[t[2]])) / 6.0;
    }
    CHECK(volume == Approx(1.0).margin(1e-12));

    // Two opposite faces missing: two holes. Vertices repeated at one position (as OBJ writers
    // do for per-corner normals) are welded for the analysis.
    TempObj two(kCubeVertices + "v 0 0 0\n" + "f 9 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n");
    TriangleMesh tube = readObj(two.path());
    CHECK(tube.boundaryEdgeCount() == 8);
    CHECK(capHoles(tube) == 2);
    CHECK(tube.boundaryEdgeCount() == 0);

    // A closed mesh is left alone.
    TempObj closed(kCubeVertices + kCubeFaces);
    TriangleMesh cube = readObj(closed.path());
    CHECK(capHoles(cube) == 0);
    CHECK(cube.triangles.size() == 12);
}
