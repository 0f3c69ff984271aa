# One image for every IEA service: iea-rsu, iea-ddm, iea-vehicle, iea-sim, iea-router, iea.
FROM python:3.11-slim
ENV PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1
WORKDIR /opt/iea
COPY pyproject.toml README.md ./
COPY protocol ./protocol
COPY rsu ./rsu
COPY ddm ./ddm
COPY vehicle ./vehicle
COPY sim ./sim
COPY deploy ./deploy
COPY scenario ./scenario
COPY models ./models
RUN pip install .
USER nobody
ENTRYPOINT ["iea"]
CMD ["--help"]
