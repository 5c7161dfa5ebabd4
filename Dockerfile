# One image for the gaitrig server and for the sensor-node agents (see docker-compose.yml).
# Build: docker build -t gaitrig .      Server: docker run -p 8000:8000 -p 8001:8001 gaitrig
FROM python:3.11-slim

# Open3D needs libGL/libgomp, Azure Kinect/Femto nodes libusb; weasyprint (PDF reports)
# needs pango/harfbuzz; fonts-wqy-microhei (5 MB) sets CJK names that DejaVu lacks.
RUN apt-get update \
 && apt-get install -y --no-install-recommends libusb-1.0-0 libgl1 libgomp1 libpango-1.0-0 \
      libpangoft2-1.0-0 libharfbuzz-subset0 fonts-dejavu-core fonts-wqy-microhei \
 && rm -rf /var/lib/apt/lists/*

WORKDIR /opt/gaitrig
COPY pyproject.toml README.md ./
COPY app ./app
COPY engine ./engine
COPY static ./static
# Editable install: the console's static files are served from /opt/gaitrig/static.
RUN pip install --no-cache-dir -e .

ENV GAITRIG_DATA_DIR=/data \
    GAITRIG_HOST=0.0.0.0 \
    GAITRIG_VIEWER_HOST=0.0.0.0 \
    PYTHONUNBUFFERED=1
VOLUME ["/data"]
EXPOSE 8000 8001
HEALTHCHECK --interval=10s --timeout=3s CMD python -c "import urllib.request,sys; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=2)" || exit 1
CMD ["gaitrig", "serve"]
