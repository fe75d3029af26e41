/* Links libcloudcontrol through its C header and checks a projection against a value
 * computed by hand, plus the error convention. Built with -std=c99 -Wall -Wextra -Werror
 * -pedantic by test.sh. */
#include "cloudcontrol.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

static int failures = 0;

static void expect(int ok, const char *what) {
    if (!ok) {
        char msg[512];
        ccp_last_error(msg, sizeof msg);
        fprintf(stderr, "FAIL: %s (last error: %s)\n", what, msg);
        failures++;
    }
}

int main(void) {
    /* Pinhole camera f = 1000 px, principal point (500, 400); nadir photo 1000 m above the
     * origin, image x east. The point (100, 50, 0) is at normalised (0.1, -0.05), i.e. pixel
     * (600, 350). */
    const double params[4] = {1000.0, 1000.0, 500.0, 400.0};
    const double center[3] = {0.0, 0.0, 1000.0};
    const double point[3] = {100.0, 50.0, 0.0};
    double pixel[2] = {0.0, 0.0};
    double direction[3];
    CcpCamera *camera = NULL;
    CcpPose pose;
    CcpStatus st;

    printf("cloudcontrol %s\n", ccp_version());
    expect(ccp_camera_new_frame(1000, 800, params, 4, &camera) == CCP_STATUS_OK, "camera");
    expect(ccp_pose_from_opk(0.0, 0.0, 0.0, center, &pose) == CCP_STATUS_OK, "pose");
    expect(ccp_project(camera, &pose, point, 1, pixel, 2) == CCP_STATUS_OK, "project");
    expect(fabs(pixel[0] - 600.0) < 1e-9 && fabs(pixel[1] - 350.0) < 1e-9, "projection value");
    printf("projected (100, 50, 0) -> (%.9f, %.9f)\n", pixel[0], pixel[1]);
    expect(ccp_back_project(camera, &pose, pixel, 1, direction, 3) == CCP_STATUS_OK, "back-project");
    expect(fabs(direction[0] / -direction[2] - 0.1) < 1e-12 && fabs(direction[1] / -direction[2] - 0.05) < 1e-12,
           "ray direction");

    /* Errors: a status and a message, never a crash. */
    st = ccp_project(NULL, &pose, point, 1, pixel, 2);
    expect(st == CCP_STATUS_NULL_POINTER, "null camera refused");
    {
        char msg[256];
        size_t need = ccp_last_error(msg, sizeof msg);
        expect(need > 1 && strstr(msg, "camera") != NULL, "null camera message");
    }
    st = ccp_project(camera, &pose, point, 1, pixel, 1);
    expect(st == CCP_STATUS_BUFFER_TOO_SMALL, "short output refused");

    ccp_camera_free(camera);
    if (failures == 0) {
        printf("C ABI check: 1 passed, 0 failed\n");
        return 0;
    }
    printf("C ABI check: 0 passed, 1 failed\n");
    return 1;
}
