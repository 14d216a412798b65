# One image for every quadmanip process: `docker run quadmanip <sub-command>`.
# compose.yaml runs the router and one container per service from this image.
FROM python:3.11-slim

# Headless MuJoCo rendering without a GPU: EGL through Mesa's software rasteriser
# (libegl-mesa0 + libgl1-mesa-dri provide the EGL vendor and the swrast driver),
# OSMesa as the fallback (MUJOCO_GL=osmesa).
RUN apt-get update \
    && apt-get install -y --no-install-recommends \
        libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libgles2 libosmesa6 \
    && rm -rf /var/lib/apt/lists/*

ENV PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    MUJOCO_GL=egl

WORKDIR /opt/quadmanip

# The heavy, rarely changing dependency first, so code edits do not re-download it.
# torch==2.13.0 is pinned to the CPU build. Where the default index serves a CUDA build,
# pass the CPU wheel index: --build-arg TORCH_INDEX_URL=<index url>.
ARG TORCH_INDEX_URL=""
RUN if [ -n "$TORCH_INDEX_URL" ]; then \
        pip install --index-url "$TORCH_INDEX_URL" "torch==2.13.0"; \
    else \
        pip install "torch==2.13.0"; \
    fi

COPY pyproject.toml setup.py README.md ./
COPY quadmanip ./quadmanip
COPY common ./common
COPY services ./services
COPY sim ./sim
COPY configs ./configs
RUN pip install . && quadmanip --help > /dev/null

# Zenoh router port (only the router container publishes it).
EXPOSE 7447
ENTRYPOINT ["quadmanip"]
CMD ["--help"]
