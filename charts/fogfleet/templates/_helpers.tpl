{{/* Chart name, truncated to the 63 characters a label value allows. */}}
{{- define "fogfleet.name" -}}
{{- default .Chart.Name .Values.nameOverride | trunc 63 | trimSuffix "-" }}
{{- end }}

{{/*
Fully qualified name: the release name when it already contains the chart name (so
`helm install fogfleet` gives fogfleet-operator, as in manifests/install/).
*/}}
{{- define "fogfleet.fullname" -}}
{{- if .Values.fullnameOverride }}
{{- .Values.fullnameOverride | trunc 63 | trimSuffix "-" }}
{{- else }}
{{- $name := default .Chart.Name .Values.nameOverride }}
{{- if contains $name .Release.Name }}
{{- .Release.Name | trunc 63 | trimSuffix "-" }}
{{- else }}
{{- printf "%s-%s" .Release.Name $name | trunc 63 | trimSuffix "-" }}
{{- end }}
{{- end }}
{{- end }}

{{/* Name of the operator's Deployment, ClusterRole and binding. */}}
{{- define "fogfleet.operatorName" -}}
{{- printf "%s-operator" (include "fogfleet.fullname" .) | trunc 63 | trimSuffix "-" }}
{{- end }}

{{- define "fogfleet.chart" -}}
{{- printf "%s-%s" .Chart.Name .Chart.Version | replace "+" "_" | trunc 63 | trimSuffix "-" }}
{{- end }}

{{- define "fogfleet.selectorLabels" -}}
app.kubernetes.io/name: {{ include "fogfleet.name" . }}
app.kubernetes.io/instance: {{ .Release.Name }}
app.kubernetes.io/component: operator
{{- end }}

{{- define "fogfleet.labels" -}}
helm.sh/chart: {{ include "fogfleet.chart" . }}
{{ include "fogfleet.selectorLabels" . }}
app.kubernetes.io/part-of: fogfleet
app.kubernetes.io/version: {{ .Chart.AppVersion | quote }}
app.kubernetes.io/managed-by: {{ .Release.Service }}
{{- end }}

{{- define "fogfleet.serviceAccountName" -}}
{{- if .Values.serviceAccount.create }}
{{- default (include "fogfleet.operatorName" .) .Values.serviceAccount.name }}
{{- else }}
{{- required "serviceAccount.name is required when serviceAccount.create is false" .Values.serviceAccount.name }}
{{- end }}
{{- end }}

{{- define "fogfleet.image" -}}
{{- printf "%s:%s" .Values.image.repository (default .Chart.AppVersion .Values.image.tag) }}
{{- end }}
